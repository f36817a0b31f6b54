//! One rollout's disturbances: a `[steps, dim]` table of f64, stored row-major in one buffer.

use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// The disturbances a rollout flies, one row of `dim` values per step, row-major in one
/// contiguous buffer (the layout of a C-ordered `[steps, dim]` array, so it crosses into numpy
/// or a CSV without reshaping).
///
/// Every row has the same length by construction. Serialised as a sequence of rows.
///
/// ```
/// use nerfsv_validation::Trajectory;
/// let x = Trajectory::from_rows(2, [[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]).unwrap();
/// assert_eq!((x.steps(), x.dim()), (3, 2));
/// assert_eq!(x.row(1), &[3.0, 4.0]);
/// assert_eq!(x.as_slice(), &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
/// assert!(Trajectory::from_rows(2, [vec![1.0, 2.0], vec![3.0]]).is_err());
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    dim: usize,
    values: Vec<f64>,
}

/// A row whose length is not the trajectory's dimension.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("step {step} has {len} disturbance values, expected {dim}")]
pub struct RaggedRow {
    pub step: usize,
    pub len: usize,
    pub dim: usize,
}

impl Trajectory {
    /// A trajectory of `dim` values per step with no steps yet.
    pub fn empty(dim: usize) -> Self {
        Self { dim, values: Vec::new() }
    }

    /// The trajectory whose rows are `values` split every `dim` (`values.len()` must be a
    /// multiple of `dim`; with `dim = 0`, empty).
    pub fn from_flat(dim: usize, values: Vec<f64>) -> Result<Self, RaggedRow> {
        if !values.len().is_multiple_of(dim) {
            return Err(RaggedRow { step: values.len() / dim.max(1), len: values.len() % dim.max(1), dim });
        }
        Ok(Self { dim, values })
    }

    /// The trajectory of these rows, each of `dim` values.
    pub fn from_rows<R: AsRef<[f64]>>(dim: usize, rows: impl IntoIterator<Item = R>) -> Result<Self, RaggedRow> {
        let mut t = Self::empty(dim);
        for row in rows {
            t.push(row.as_ref())?;
        }
        Ok(t)
    }

    /// Appends one step's row.
    pub fn push(&mut self, row: &[f64]) -> Result<(), RaggedRow> {
        if row.len() != self.dim {
            return Err(RaggedRow { step: self.steps(), len: row.len(), dim: self.dim });
        }
        self.values.extend_from_slice(row);
        Ok(())
    }

    /// Number of steps (rows).
    pub fn steps(&self) -> usize {
        self.values.len().checked_div(self.dim).unwrap_or(0)
    }

    /// Values per step.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// True when there are no steps.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Step `t`'s row. Panics past the last step.
    pub fn row(&self, t: usize) -> &[f64] {
        &self.values[t * self.dim..(t + 1) * self.dim]
    }

    /// The rows, in step order.
    pub fn rows(&self) -> impl ExactSizeIterator<Item = &[f64]> + '_ {
        // `chunks_exact(0)` panics; a zero-dimensional trajectory has no values and no rows.
        self.values.chunks_exact(self.dim.max(1))
    }

    /// All values, row-major `[steps, dim]`.
    pub fn as_slice(&self) -> &[f64] {
        &self.values
    }

    /// The values, row-major `[steps, dim]`.
    pub fn into_vec(self) -> Vec<f64> {
        self.values
    }
}

impl Serialize for Trajectory {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(self.rows())
    }
}

impl<'de> Deserialize<'de> for Trajectory {
    /// From a sequence of rows of equal length (an empty sequence has dimension 0).
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let rows = Vec::<Vec<f64>>::deserialize(d)?;
        let dim = rows.first().map_or(0, Vec::len);
        Self::from_rows(dim, &rows).map_err(D::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_round_trip_through_serde_and_refuse_ragged_input() {
        let x = Trajectory::from_rows(3, [[0.5, -1.0, 2.0], [1e-300, 3.0, -0.0]]).unwrap();
        let text = serde_json::to_string(&x).unwrap();
        assert_eq!(text, "[[0.5,-1.0,2.0],[1e-300,3.0,-0.0]]");
        let back: Trajectory = serde_json::from_str(&text).unwrap();
        assert_eq!(
            back.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            x.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(back.dim(), 3);
        assert!(serde_json::from_str::<Trajectory>("[[1.0,2.0],[3.0]]").is_err());
        assert_eq!(serde_json::from_str::<Trajectory>("[]").unwrap().steps(), 0);
    }

    #[test]
    fn flat_values_must_fill_whole_rows() {
        assert_eq!(Trajectory::from_flat(2, vec![1.0, 2.0, 3.0]).unwrap_err(), RaggedRow { step: 1, len: 1, dim: 2 });
        assert!(Trajectory::from_flat(0, vec![1.0]).is_err());
        let t = Trajectory::from_flat(2, vec![1.0, 2.0, 3.0, 4.0]).unwrap();
        assert_eq!(t.rows().collect::<Vec<_>>(), vec![&[1.0, 2.0][..], &[3.0, 4.0][..]]);
        assert_eq!(Trajectory::empty(0).rows().count(), 0);
    }
}
