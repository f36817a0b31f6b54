//! Rollouts flown in other processes or on other machines (the Python package's Ray executor):
//! the seam a [`DroneSystem`](crate::DroneSystem) hands its batches to, and the exact byte
//! encodings of what crosses it.
//!
//! A driver runs the search as always (the same samplers, journal, records and outputs); only
//! the rollouts themselves fly elsewhere, each on a worker that holds the same model, fields and
//! config and returns what [`System::run`](nerfsv_validation::System::run) would have returned
//! here. Floats cross as their bits, so a distributed search writes the same bytes as a local
//! one with the same seed.

use nerfsv_sim::{EstimatorKind, ImageUpdate, WorldKind, IMAGE_COLUMNS};
use nerfsv_validation::{Job, Outcome, Trajectory, ValidationError};

/// Which drone system a batch of jobs is for: the world it flies in and its estimator.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RemoteSpec {
    pub world: WorldKind,
    pub estimator: EstimatorKind,
}

/// What a [`RemoteRollouts`] hands each result to: `(job index, result bytes)`.
pub type Returned<'a> = &'a mut dyn FnMut(usize, &[u8]) -> Result<(), ValidationError>;

/// Flies batches of rollouts somewhere else.
pub trait RemoteRollouts: Sync {
    /// Flies `jobs` (encoded with [`encode_job`]) of the system `spec` describes, on the model,
    /// fields and config this runner was made for, and calls `finished(job index, result)` with
    /// each result ([`encode_result`]'s bytes) as it comes back, in any order; every job must
    /// come back exactly once.
    fn run(&self, spec: RemoteSpec, jobs: &[Vec<u8>], finished: Returned<'_>) -> Result<(), ValidationError>;
}

/// A little-endian writer of the encodings below.
#[derive(Default)]
struct Writer(Vec<u8>);

impl Writer {
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    fn f64s(&mut self, v: &[f64]) {
        self.u64(v.len() as u64);
        v.iter().for_each(|&x| self.f64(x));
    }
    fn triples(&mut self, v: &[[f64; 3]]) {
        self.u64(v.len() as u64);
        v.iter().flatten().for_each(|&x| self.f64(x));
    }
    fn option(&mut self, v: Option<usize>) {
        self.u64(v.map_or(u64::MAX, |s| s as u64));
    }
}

/// The matching reader; every read checks the length left.
struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn u64(&mut self) -> Result<u64, ValidationError> {
        let (head, rest) = self
            .0
            .split_first_chunk::<8>()
            .ok_or_else(|| ValidationError::Executor("a truncated rollout message".into()))?;
        self.0 = rest;
        Ok(u64::from_le_bytes(*head))
    }
    fn f64(&mut self) -> Result<f64, ValidationError> {
        self.u64().map(f64::from_bits)
    }
    fn len(&mut self) -> Result<usize, ValidationError> {
        let n = self.u64()? as usize;
        if n > self.0.len() / 8 {
            return Err(ValidationError::Executor(format!("a rollout message announces {n} values past its end")));
        }
        Ok(n)
    }
    fn f64s(&mut self) -> Result<Vec<f64>, ValidationError> {
        let n = self.len()?;
        (0..n).map(|_| self.f64()).collect()
    }
    fn triples(&mut self) -> Result<Vec<[f64; 3]>, ValidationError> {
        let n = self.len()?;
        (0..n).map(|_| Ok([self.f64()?, self.f64()?, self.f64()?])).collect()
    }
    fn option(&mut self) -> Result<Option<usize>, ValidationError> {
        self.u64().map(|v| (v != u64::MAX).then_some(v as usize))
    }
    fn end(self) -> Result<(), ValidationError> {
        if self.0.is_empty() {
            Ok(())
        } else {
            Err(ValidationError::Executor(format!("{} bytes past the end of a rollout message", self.0.len())))
        }
    }
}

/// One job as bytes: seed, dimension, disturbances (bits of each f64).
pub fn encode_job(&(x, seed): &Job<'_>) -> Vec<u8> {
    let mut w = Writer::default();
    w.u64(seed);
    w.u64(x.dim() as u64);
    w.f64s(x.as_slice());
    w.0
}

/// [`encode_job`]'s bytes back: (disturbances, seed).
pub fn decode_job(bytes: &[u8]) -> Result<(Trajectory, u64), ValidationError> {
    let mut r = Reader(bytes);
    let seed = r.u64()?;
    let dim = r.u64()? as usize;
    let values = r.f64s()?;
    r.end()?;
    let x = Trajectory::from_flat(dim, values).map_err(|e| ValidationError::Executor(e.to_string()))?;
    Ok((x, seed))
}

/// What a rollout flown elsewhere returns: its outcome and the filter's record of each camera
/// image ([`ImageUpdate::to_row`]'s numbers).
pub fn encode_result(outcome: &Outcome, images: &[ImageUpdate]) -> Vec<u8> {
    let mut w = Writer::default();
    w.f64(outcome.score);
    w.option(outcome.collision_step);
    w.option(outcome.lost_step);
    w.f64s(&outcome.step_scores);
    w.triples(&outcome.step_positions);
    w.triples(&outcome.step_attitudes);
    w.f64s(&outcome.step_uncertainty);
    w.f64s(&images.iter().flat_map(ImageUpdate::to_row).collect::<Vec<_>>());
    w.0
}

/// [`encode_result`]'s bytes back.
pub fn decode_result(bytes: &[u8]) -> Result<(Outcome, Vec<ImageUpdate>), ValidationError> {
    let mut r = Reader(bytes);
    let score = r.f64()?;
    let collision_step = r.option()?;
    let lost_step = r.option()?;
    let outcome = Outcome {
        score,
        collision_step,
        lost_step,
        step_scores: r.f64s()?,
        step_positions: r.triples()?,
        step_attitudes: r.triples()?,
        step_uncertainty: r.f64s()?,
    };
    let flat = r.f64s()?;
    r.end()?;
    let bad = || ValidationError::Executor(format!("image records come in rows of {}", IMAGE_COLUMNS.len()));
    if flat.len() % IMAGE_COLUMNS.len() != 0 {
        return Err(bad());
    }
    let images = flat
        .chunks_exact(IMAGE_COLUMNS.len())
        .map(|row| ImageUpdate::from_row(row.try_into().expect("a whole row")).map_err(|_| bad()))
        .collect::<Result<_, _>>()?;
    Ok((outcome, images))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jobs_and_results_cross_bit_for_bit_and_damage_is_refused() {
        let x = Trajectory::from_rows(2, [[0.1 + 0.2, -0.0], [f64::MIN_POSITIVE, 1e300]]).unwrap();
        let bytes = encode_job(&(&x, u64::MAX - 3));
        let (back, seed) = decode_job(&bytes).unwrap();
        assert_eq!(seed, u64::MAX - 3);
        assert_eq!(
            back.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            x.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        assert!(decode_job(&bytes[..bytes.len() - 1]).is_err());

        let outcome = Outcome {
            score: -0.012,
            collision_step: Some(3),
            lost_step: None,
            step_scores: vec![0.5, f64::NAN, f64::INFINITY],
            step_positions: vec![[1.0, 2.0, 3.0], [f64::NAN; 3]],
            step_attitudes: vec![[0.1, -0.2, 1.0 / 3.0]],
            step_uncertainty: Vec::new(),
        };
        // Two images: every column a value its field may hold (flags 0 or 1, counts whole).
        let row = |k: f64| -> [f64; IMAGE_COLUMNS.len()] {
            std::array::from_fn(|i| match i {
                9..=11 | 17 => k,
                0 | 1 | 15 => i as f64 + k,
                _ => i as f64 / 3.0 + k,
            })
        };
        let images: Vec<ImageUpdate> = [0.0, 1.0].map(|k| ImageUpdate::from_row(&row(k)).unwrap()).into();
        let bytes = encode_result(&outcome, &images);
        let (o, back) = decode_result(&bytes).unwrap();
        assert_eq!(back, images);
        assert_eq!((o.score, o.collision_step, o.lost_step), (outcome.score, Some(3), None));
        assert_eq!(o.step_scores[2], f64::INFINITY);
        assert!(o.step_scores[1].is_nan() && o.step_positions[1][0].is_nan());
        assert_eq!(o.step_attitudes, outcome.step_attitudes);
        let mut long = bytes.clone();
        long.push(0);
        assert!(decode_result(&long).is_err() && decode_result(&bytes[..20]).is_err());
    }
}
