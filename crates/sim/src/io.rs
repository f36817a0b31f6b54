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

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Rotation3, UnitQuaternion};

use crate::dynamics::{Disturbance, State};
use crate::rollout::Rollout;

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
}
