//! Files a flight reads and writes: disturbance sequences and trajectories, as CSV.
//!
//! A disturbance file has one row per step and the 12 columns of [`DISTURBANCE_COLUMNS`]
//! (position, velocity, rotation vector, angular velocity), with that header line or none;
//! values beyond [`MAX_PRIOR_SIGMAS`] standard deviations of the disturbance prior are refused
//! (such a state leaves any world the drone can be simulated in).
//! A trajectory file has one row per checked substep: step, substep, time, the true and the
//! estimated state (position, velocity, rotation as a unit quaternion w x y z, body angular
//! velocity), the estimator's expected position and attitude errors (`√tr P`, metres and
//! degrees; 0 for the truth estimator) and the crash criterion's clearance (empty where the body
//! left the field's grid).
//! An image log has one row per camera image, the filter's record of it ([`IMAGE_COLUMNS`]):
//! the estimate's errors before and after, the normalised innovation and estimation errors
//! squared, whether the gate took the image, whether the estimator relocalised or lost track
//! there, the fit's variance factor, the filter's expected errors, the renders the fit took, its
//! colour RMSE, and whether it undid the relocalisation before it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};

use crate::dynamics::{Disturbance, State};
use crate::rollout::{ImageUpdate, Rollout};

/// Header of a disturbance file.
pub const DISTURBANCE_COLUMNS: [&str; Disturbance::DIM] =
    ["dp_x", "dp_y", "dp_z", "dv_x", "dv_y", "dv_z", "dr_x", "dr_y", "dr_z", "dw_x", "dw_y", "dw_z"];

/// A disturbance file that cannot be used; names the file, the row (1-based line) and column.
#[derive(Debug, thiserror::Error)]
pub enum DisturbanceFileError {
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{path}: line {line}: expected 12 columns ({}), found {found}", DISTURBANCE_COLUMNS.join(","))]
    Columns { path: PathBuf, line: usize, found: usize },
    #[error("{path}: line {line}, column {column} ({name}): {found:?} is not a finite number")]
    Value { path: PathBuf, line: usize, column: usize, name: &'static str, found: String },
    #[error(
        "{path}: line {line}, column {column} ({name}): {found} is more than {MAX_PRIOR_SIGMAS} standard deviations \
         of the disturbance prior ({limit} at most)"
    )]
    OutsidePrior { path: PathBuf, line: usize, column: usize, name: &'static str, found: String, limit: f64 },
    #[error("{path}: expected one row per step ({expected}), found {found} rows")]
    Rows { path: PathBuf, expected: usize, found: usize },
}

/// The largest disturbance accepted from a file, in standard deviations of the prior.
pub const MAX_PRIOR_SIGMAS: f64 = 50.0;

/// A disturbance component `v` of column `c` as rollouts accept it: finite and within
/// [`MAX_PRIOR_SIGMAS`] of the prior's standard deviation `prior_std[c]` (a column whose prior is 0
/// bounded by the widest; no bound when every prior is 0). `Err(Some(limit))` beyond the bound,
/// `Err(None)` when not finite. The rule of disturbance files and of every other source.
pub fn check_component(v: f64, c: usize, prior_std: &[f64]) -> Result<f64, Option<f64>> {
    let widest = prior_std.iter().copied().fold(0.0, f64::max);
    let limit = MAX_PRIOR_SIGMAS * prior_std.get(c).copied().filter(|&s| s > 0.0).unwrap_or(widest);
    match v {
        v if !v.is_finite() => Err(None),
        v if widest == 0.0 || v.abs() <= limit => Ok(v),
        _ => Err(Some(limit)),
    }
}

/// Reads `steps` disturbances from a CSV file; `prior_std` is the disturbance prior's standard
/// deviation per column (a column whose prior is 0 is bounded by the largest of them).
pub fn read_disturbances(
    path: &Path,
    steps: usize,
    prior_std: &[f64],
) -> Result<Vec<Disturbance>, DisturbanceFileError> {
    let text = std::fs::read_to_string(path).map_err(|e| DisturbanceFileError::Io { path: path.into(), error: e })?;
    parse_disturbances(&text, steps, prior_std, path)
}

/// Parses a disturbance CSV (see the module docs) read from `path`; blank lines are skipped.
pub fn parse_disturbances(
    text: &str,
    steps: usize,
    prior_std: &[f64],
    path: &Path,
) -> Result<Vec<Disturbance>, DisturbanceFileError> {
    let mut out = Vec::with_capacity(steps);
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != 12 {
            return Err(DisturbanceFileError::Columns { path: path.into(), line: n + 1, found: fields.len() });
        }
        if out.is_empty() && fields.iter().zip(DISTURBANCE_COLUMNS).all(|(f, c)| *f == c) {
            continue;
        }
        let mut d = [0.0; Disturbance::DIM];
        for (c, f) in fields.iter().enumerate() {
            d[c] = match f.parse::<f64>().map(|v| check_component(v, c, prior_std)) {
                Ok(Ok(v)) => v,
                Ok(Err(Some(limit))) => {
                    return Err(DisturbanceFileError::OutsidePrior {
                        path: path.into(),
                        line: n + 1,
                        column: c + 1,
                        name: DISTURBANCE_COLUMNS[c],
                        found: f.to_string(),
                        limit,
                    })
                }
                _ => {
                    return Err(DisturbanceFileError::Value {
                        path: path.into(),
                        line: n + 1,
                        column: c + 1,
                        name: DISTURBANCE_COLUMNS[c],
                        found: f.to_string(),
                    })
                }
            };
        }
        out.push(Disturbance(d));
    }
    if out.len() != steps {
        return Err(DisturbanceFileError::Rows { path: path.into(), expected: steps, found: out.len() });
    }
    Ok(out)
}

/// Disturbances as CSV with a header, one row per step (round-trips exactly through
/// [`parse_disturbances`]: Rust prints the shortest decimal that reads back to the same f64).
pub fn disturbances_csv(ds: &[Disturbance]) -> String {
    let mut s = DISTURBANCE_COLUMNS.join(",");
    s.push('\n');
    for d in ds {
        let row: Vec<String> = d.0.iter().map(|v| v.to_string()).collect();
        s.push_str(&row.join(","));
        s.push('\n');
    }
    s
}

fn quaternion(r: &Matrix3<f64>) -> [f64; 4] {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r));
    [q.w, q.i, q.j, q.k]
}

fn push_state(s: &mut String, st: &State) {
    let q = quaternion(&st.rotation);
    let v = [
        st.position.x,
        st.position.y,
        st.position.z,
        st.velocity.x,
        st.velocity.y,
        st.velocity.z,
        q[0],
        q[1],
        q[2],
        q[3],
        st.omega.x,
        st.omega.y,
        st.omega.z,
    ];
    for x in v {
        let _ = write!(s, ",{x}");
    }
}

/// The rollout's substeps as CSV (see the module docs for the columns).
pub fn trajectory_csv(r: &Rollout) -> String {
    let state_cols = |p: &str| {
        ["x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "wx", "wy", "wz"]
            .map(|c| format!("{p}_{c}"))
            .join(",")
    };
    let mut s = format!(
        "step,substep,time_s,{},{},est_position_sd_m,est_attitude_sd_deg,clearance_m,collided\n",
        state_cols("true"),
        state_cols("est")
    );
    for sub in &r.substeps {
        let _ = write!(s, "{},{},{}", sub.step, sub.substep, sub.time);
        push_state(&mut s, &sub.truth);
        push_state(&mut s, &sub.estimate);
        let _ = write!(s, ",{},{}", sub.estimate_spread[0], sub.estimate_spread[1].to_degrees());
        match sub.clearance {
            Some(c) => {
                let _ = writeln!(s, ",{c},{}", u8::from(c <= 0.0));
            }
            None => s.push_str(",,0\n"),
        }
    }
    s
}

/// A trajectory file that cannot be read; names the file and the line (1-based).
#[derive(Debug, thiserror::Error)]
pub enum TrajectoryFileError {
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{path}: no column {column} in its header (a trajectory CSV as nerfsv writes one)")]
    Column { path: PathBuf, column: String },
    #[error("{path}: line {line}, column {column}: {found:?} is not a finite number")]
    Value { path: PathBuf, line: usize, column: String, found: String },
}

/// A pose of a trajectory file: where the body was (`truth`) or was believed to be
/// (`estimate`), position (m) and body-to-world rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrajectoryPose {
    pub time: f64,
    pub position: Vector3<f64>,
    pub rotation: Matrix3<f64>,
}

/// One row of a trajectory file ([`trajectory_csv`]): its time and the true and estimated poses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrajectoryRow {
    pub truth: TrajectoryPose,
    pub estimate: TrajectoryPose,
}

/// Reads a trajectory file's poses, row by row (the columns found by their header names, so
/// columns added later do not break it).
pub fn read_trajectory(path: &Path) -> Result<Vec<TrajectoryRow>, TrajectoryFileError> {
    let text = std::fs::read_to_string(path).map_err(|error| TrajectoryFileError::Io { path: path.into(), error })?;
    parse_trajectory(&text, path)
}

/// [`read_trajectory`] on a file's text; `path` names it in errors.
pub fn parse_trajectory(text: &str, path: &Path) -> Result<Vec<TrajectoryRow>, TrajectoryFileError> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').map(str::trim).collect();
    let column = |name: String| match header.iter().position(|c| *c == name) {
        Some(i) => Ok((i, name)),
        None => Err(TrajectoryFileError::Column { path: path.into(), column: name }),
    };
    let pose_columns = |prefix: &str| -> Result<Vec<(usize, String)>, TrajectoryFileError> {
        ["x", "y", "z", "qw", "qx", "qy", "qz"].iter().map(|c| column(format!("{prefix}_{c}"))).collect()
    };
    let time = column("time_s".into())?;
    let (truth, estimate) = (pose_columns("true")?, pose_columns("est")?);
    let mut rows = Vec::new();
    for (n, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let cells: Vec<&str> = line.split(',').collect();
        let value = |(i, name): &(usize, String)| -> Result<f64, TrajectoryFileError> {
            let cell = cells.get(*i).map_or("", |c| c.trim());
            cell.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| TrajectoryFileError::Value {
                path: path.into(),
                line: n + 2,
                column: name.clone(),
                found: cell.to_owned(),
            })
        };
        let t = value(&time)?;
        let pose = |cols: &[(usize, String)]| -> Result<TrajectoryPose, TrajectoryFileError> {
            let v: Vec<f64> = cols.iter().map(value).collect::<Result<_, _>>()?;
            let q = UnitQuaternion::from_quaternion(Quaternion::new(v[3], v[4], v[5], v[6]));
            Ok(TrajectoryPose {
                time: t,
                position: Vector3::new(v[0], v[1], v[2]),
                rotation: q.to_rotation_matrix().into_inner(),
            })
        };
        rows.push(TrajectoryRow { truth: pose(&truth)?, estimate: pose(&estimate)? });
    }
    Ok(rows)
}

/// Header of an image log ([`images_csv`]), one column per field of [`ImageUpdate`] in its order
/// (booleans as 0 or 1).
pub const IMAGE_COLUMNS: [&str; 18] = [
    "step",
    "substep",
    "time_s",
    "predicted_position_error_m",
    "predicted_attitude_error_deg",
    "position_error_m",
    "attitude_error_deg",
    "nees",
    "nis",
    "accepted",
    "relocalised",
    "lost",
    "variance_factor",
    "position_sd_m",
    "attitude_sd_deg",
    "renders",
    "photometric_rmse",
    "relocalisation_undone",
];

impl ImageUpdate {
    /// The record as numbers in [`IMAGE_COLUMNS`]' order (booleans 0 or 1, counts exact).
    pub fn to_row(&self) -> [f64; IMAGE_COLUMNS.len()] {
        [
            self.step as f64,
            self.substep as f64,
            self.time,
            self.predicted_position_error_m,
            self.predicted_rotation_error_deg,
            self.position_error_m,
            self.rotation_error_deg,
            self.nees,
            self.nis,
            f64::from(u8::from(self.accepted)),
            f64::from(u8::from(self.relocalised)),
            f64::from(u8::from(self.lost)),
            self.variance_factor,
            self.position_spread_m,
            self.rotation_spread_deg,
            self.renders as f64,
            self.photometric_rmse,
            f64::from(u8::from(self.relocalisation_undone)),
        ]
    }

    /// [`ImageUpdate::to_row`]'s numbers back; the index of the first column that is not what its
    /// field holds (a count that is not a whole number, a flag that is not 0 or 1).
    pub fn from_row(v: &[f64; IMAGE_COLUMNS.len()]) -> Result<Self, usize> {
        let count = |i: usize| match v[i] {
            x if x >= 0.0 && x.fract() == 0.0 && x < 2f64.powi(53) => Ok(x as usize),
            _ => Err(i),
        };
        let flag = |i: usize| match v[i] {
            0.0 => Ok(false),
            1.0 => Ok(true),
            _ => Err(i),
        };
        Ok(Self {
            step: count(0)?,
            substep: count(1)?,
            time: v[2],
            predicted_position_error_m: v[3],
            predicted_rotation_error_deg: v[4],
            position_error_m: v[5],
            rotation_error_deg: v[6],
            nees: v[7],
            nis: v[8],
            accepted: flag(9)?,
            relocalised: flag(10)?,
            lost: flag(11)?,
            variance_factor: v[12],
            position_spread_m: v[13],
            rotation_spread_deg: v[14],
            renders: count(15)?,
            photometric_rmse: v[16],
            relocalisation_undone: flag(17)?,
        })
    }
}

/// An image log as CSV with its header (see the module docs); reads back bit for bit through
/// [`parse_images`] (NaN and infinities included).
pub fn images_csv(updates: &[ImageUpdate]) -> String {
    let mut s = IMAGE_COLUMNS.join(",");
    s.push('\n');
    for u in updates {
        let row: Vec<String> = u.to_row().iter().map(f64::to_string).collect();
        s.push_str(&row.join(","));
        s.push('\n');
    }
    s
}

/// An image log that cannot be read; names the file and the line (1-based).
#[derive(Debug, thiserror::Error)]
pub enum ImageLogError {
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{path}: line 1: expected the header {}", IMAGE_COLUMNS.join(","))]
    Header { path: PathBuf },
    #[error("{path}: line {line}: expected {} columns, found {found}", IMAGE_COLUMNS.len())]
    Columns { path: PathBuf, line: usize, found: usize },
    #[error("{path}: line {line}, column {column}: {found:?} is not a value of the column")]
    Value { path: PathBuf, line: usize, column: &'static str, found: String },
}

/// Reads an image log ([`images_csv`]).
pub fn read_images(path: &Path) -> Result<Vec<ImageUpdate>, ImageLogError> {
    let text = std::fs::read_to_string(path).map_err(|error| ImageLogError::Io { path: path.into(), error })?;
    parse_images(&text, path)
}

/// [`read_images`] on a file's text; `path` names it in errors.
pub fn parse_images(text: &str, path: &Path) -> Result<Vec<ImageUpdate>, ImageLogError> {
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    if lines.next().map(|(_, l)| l.trim()) != Some(IMAGE_COLUMNS.join(",").as_str()) {
        return Err(ImageLogError::Header { path: path.into() });
    }
    lines
        .map(|(n, line)| {
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            if cells.len() != IMAGE_COLUMNS.len() {
                return Err(ImageLogError::Columns { path: path.into(), line: n + 1, found: cells.len() });
            }
            let bad = |i: usize| ImageLogError::Value {
                path: path.into(),
                line: n + 1,
                column: IMAGE_COLUMNS[i],
                found: cells[i].to_owned(),
            };
            let mut v = [0.0; IMAGE_COLUMNS.len()];
            for (i, cell) in cells.iter().enumerate() {
                v[i] = cell.parse().map_err(|_| bad(i))?;
            }
            ImageUpdate::from_row(&v).map_err(bad)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disturbances_round_trip_exactly() {
        // Values with long decimal expansions, both signs, tiny and large.
        let ds: Vec<Disturbance> = (0..6)
            .map(|t| {
                Disturbance(std::array::from_fn(|i| ((t * 12 + i) as f64 - 30.0) / 7.0 * 10f64.powi(i as i32 - 8)))
            })
            .collect();
        let back = parse_disturbances(&disturbances_csv(&ds), 6, &[1e6; 12], Path::new("d.csv")).unwrap();
        assert_eq!(ds, back);
        // Without a header too.
        let body: String = disturbances_csv(&ds).lines().skip(1).map(|l| format!("{l}\n")).collect();
        assert_eq!(parse_disturbances(&body, 6, &[1e6; 12], Path::new("d.csv")).unwrap(), ds);
    }

    #[test]
    fn bad_disturbance_files_name_line_and_column() {
        let path = Path::new("d.csv");
        let row = "0,0,0,0,0,0,0,0,0,0,0,0\n";
        let e = parse_disturbances(&format!("{row}0,0,0\n"), 2, &Disturbance::PAPER_STD, path).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!("d.csv: line 2: expected 12 columns ({}), found 3", DISTURBANCE_COLUMNS.join(","))
        );
        let e = parse_disturbances(&format!("{row}0,0,0,0,0,0,0,0,nan,0,0,0\n"), 2, &Disturbance::PAPER_STD, path)
            .unwrap_err();
        assert_eq!(e.to_string(), "d.csv: line 2, column 9 (dr_z): \"nan\" is not a finite number");
        let e = parse_disturbances(&format!("{row}0,0,0,0,0,1e999,0,0,0,0,0,0\n"), 2, &Disturbance::PAPER_STD, path)
            .unwrap_err();
        assert!(e.to_string().contains("column 6 (dv_z)"), "{e}");
        let e = parse_disturbances(row, 2, &Disturbance::PAPER_STD, path).unwrap_err();
        assert_eq!(e.to_string(), "d.csv: expected one row per step (2), found 1 rows");
        // Finite but far outside the prior: refused, naming row and column.
        let e = parse_disturbances(&format!("{row}0,0,0,1e300,0,0,0,0,0,0,0,0\n"), 2, &Disturbance::PAPER_STD, path)
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "d.csv: line 2, column 4 (dv_x): 1e300 is more than 50 standard deviations of the disturbance prior (0.5 at most)"
        );
        // 50σ itself is accepted.
        assert!(
            parse_disturbances(&format!("{row}1,0,0,0,0,0,0,0,0,0,0,0\n"), 2, &Disturbance::PAPER_STD, path).is_ok()
        );
    }

    /// What [`trajectory_csv`] writes reads back as the same poses (the rotation through its
    /// quaternion, to rounding), found by the header's names wherever the columns sit.
    #[test]
    fn trajectory_poses_round_trip_and_bad_cells_are_named() {
        use crate::dynamics::so3_exp;
        let state = |k: f64| State {
            position: Vector3::new(k, -2.0 * k, 0.5 + k),
            rotation: so3_exp(&Vector3::new(0.3 * k, -0.2, 1.1 * k)),
            ..State::at_rest(Vector3::zeros(), 0.0)
        };
        let substeps = (0..4)
            .map(|i| crate::rollout::Substep {
                step: i / 2,
                substep: i % 2,
                time: 0.05 * i as f64,
                truth: state(i as f64 * 0.37),
                estimate: state(i as f64 * 0.37 + 0.01),
                estimate_spread: [0.01, 0.02],
                clearance: (i != 2).then_some(0.3),
            })
            .collect::<Vec<_>>();
        let rollout = Rollout {
            substeps: substeps.clone(),
            updates: Vec::new(),
            first_collision: None,
            left_grid: None,
            diverged: None,
            min_clearance: Some(0.3),
            goal_distance_m: 1.0,
            reached_goal: false,
        };
        let rows = parse_trajectory(&trajectory_csv(&rollout), Path::new("t.csv")).unwrap();
        assert_eq!(rows.len(), 4);
        for (row, sub) in rows.iter().zip(&substeps) {
            assert_eq!(row.truth.time, sub.time);
            assert_eq!(row.truth.position, sub.truth.position);
            assert!((row.truth.rotation - sub.truth.rotation).abs().max() < 1e-12);
            assert_eq!(row.estimate.position, sub.estimate.position);
            assert!((row.estimate.rotation - sub.estimate.rotation).abs().max() < 1e-12);
        }
        let text = trajectory_csv(&rollout).replacen(&format!("{}", substeps[1].truth.position.y), "x", 1);
        let e = parse_trajectory(&text, Path::new("t.csv")).unwrap_err().to_string();
        assert_eq!(e, "t.csv: line 3, column true_y: \"x\" is not a finite number");
        let e = parse_trajectory("step,time_s\n", Path::new("t.csv")).unwrap_err().to_string();
        assert!(e.contains("no column true_x"), "{e}");
    }

    /// An image log reads back bit for bit, NaN and infinities included; a damaged one is named
    /// by its line and column.
    #[test]
    fn image_logs_round_trip_bit_for_bit_and_bad_cells_are_named() {
        let update = |k: usize| ImageUpdate {
            step: k / 3,
            substep: k % 3,
            time: 0.1 * k as f64 + 1.0 / 3.0,
            predicted_position_error_m: 0.1 + 0.2 * k as f64,
            predicted_rotation_error_deg: f64::MIN_POSITIVE,
            position_error_m: 1e-300,
            rotation_error_deg: 123456.789e-7,
            nees: f64::INFINITY,
            nis: if k == 1 { f64::NAN } else { 7.25 },
            accepted: k != 1,
            relocalised: k == 2,
            lost: k == 1,
            variance_factor: 0.0,
            position_spread_m: -0.0,
            rotation_spread_deg: f64::MAX,
            renders: 10 + k,
            photometric_rmse: 0.012,
            relocalisation_undone: k == 0,
        };
        let log: Vec<ImageUpdate> = (0..4).map(update).collect();
        let text = images_csv(&log);
        let back = parse_images(&text, Path::new("i.csv")).unwrap();
        let bits = |l: &[ImageUpdate]| -> Vec<u64> { l.iter().flat_map(|u| u.to_row()).map(f64::to_bits).collect() };
        assert_eq!(bits(&back), bits(&log));
        assert!(back[1].nis.is_nan() && back[2].relocalised && !back[1].accepted);
        // The cell of the image log's `line` (1-based) and `column` replaced by `value`.
        let damaged = |line: usize, column: &str, value: &str| -> String {
            let at = IMAGE_COLUMNS.iter().position(|c| *c == column).unwrap();
            let mut lines: Vec<Vec<String>> = text.lines().map(|l| l.split(',').map(String::from).collect()).collect();
            lines[line - 1][at] = value.into();
            lines.iter().map(|l| l.join(",") + "\n").collect()
        };
        for (line, column, value) in
            [(3, "renders", "1.5"), (4, "relocalised", "2"), (5, "nis", "x"), (2, "step", "-1")]
        {
            let e = parse_images(&damaged(line, column, value), Path::new("i.csv")).unwrap_err().to_string();
            assert_eq!(e, format!("i.csv: line {line}, column {column}: {value:?} is not a value of the column"));
        }
        let e = parse_images("step,time\n", Path::new("i.csv")).unwrap_err().to_string();
        assert!(e.starts_with("i.csv: line 1: expected the header step,substep,"), "{e}");
        assert!(parse_images(&images_csv(&[]), Path::new("i.csv")).unwrap().is_empty());
    }
}
