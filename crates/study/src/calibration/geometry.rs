//! The NeRFs' geometry along the route against the ground truth's: what the perception error
//! model cannot see. NeRF-sim detects a crash in its NeRF's signed field, so a field whose surface
//! lies nearer the route than the real one crashes rollouts the real world would not, however
//! well the camera's errors are calibrated. Compared where it matters, along the planned path,
//! for a world whose ground-truth field is known (a built-in scene or a mesh).

use nalgebra::{Point3, Vector3};
use nerfsv_collision::SdfGrid;
use nerfsv_sim::PlannedPath;
use serde::{Deserialize, Serialize};

/// Points of the path closer than this to the ground truth's geometry (m) are "near" it: where
/// a field's error can turn a pass into a crash.
pub const NEAR_M: f64 = 0.25;

/// Spacing of the compared points along the path (m).
pub const SPACING_M: f64 = 0.01;

/// Each field's signed distance along the route against the ground truth's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RouteGeometry {
    /// Points compared: the planned path every [`SPACING_M`], the body's centre.
    pub points: usize,
    /// Of them, the ones within [`NEAR_M`] of the ground truth's geometry.
    pub near_points: usize,
    /// The ground truth's least distance from the path (m): the route's tight pass.
    pub gt_min_distance_m: f64,
    /// Where along the path it lies, as a fraction of the path's length.
    pub tight_pass_fraction: f64,
    /// One row per NeRF field: the deployed model's, then each ensemble member's.
    pub fields: Vec<FieldAlongRoute>,
}

/// One NeRF field along the route. Errors are the field's distance less the ground truth's:
/// negative where the NeRF's surface lies nearer the route than the real one (NeRF-sim crashes
/// sooner there).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldAlongRoute {
    /// `deployed`, or `member K`.
    pub field: String,
    /// Its least distance from the path (m).
    pub min_distance_m: f64,
    /// Its error at the ground truth's tight pass (m).
    pub error_at_tight_pass_m: f64,
    /// Mean, least and greatest error over the near points (m).
    pub near_mean_error_m: f64,
    pub near_min_error_m: f64,
    pub near_max_error_m: f64,
}

/// The planned path's points every [`SPACING_M`], both ends included.
pub fn route_points(path: &PlannedPath) -> Vec<Vector3<f64>> {
    let length = path.length();
    let n = (length / SPACING_M).ceil().max(1.0) as usize;
    (0..=n).map(|i| path.point_at(length * i as f64 / n as f64)).collect()
}

/// `fields` (named) against `gt` at `points`; points off any grid are left out. `None` when no
/// point lies on every grid.
pub fn route_geometry(points: &[Vector3<f64>], gt: &SdfGrid, fields: &[(String, &SdfGrid)]) -> Option<RouteGeometry> {
    let at = |field: &SdfGrid, p: &Vector3<f64>| {
        field.distance(Point3::new(p.x as f32, p.y as f32, p.z as f32)).in_grid().map(f64::from)
    };
    // Each kept point's fraction along the route, the ground truth's distance and each field's.
    let last = points.len().saturating_sub(1).max(1) as f64;
    let kept: Vec<(f64, f64, Vec<f64>)> = points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let g = at(gt, p)?;
            let f: Option<Vec<f64>> = fields.iter().map(|(_, field)| at(field, p)).collect();
            Some((i as f64 / last, g, f?))
        })
        .collect();
    let tight = kept.iter().min_by(|a, b| a.1.total_cmp(&b.1))?;
    let near: Vec<&(f64, f64, Vec<f64>)> = kept.iter().filter(|k| k.1 < NEAR_M).collect();
    let rows = fields
        .iter()
        .enumerate()
        .map(|(j, (name, _))| {
            let errors: Vec<f64> = near.iter().map(|k| k.2[j] - k.1).collect();
            // NaN for each with no near point.
            let (mean, least, greatest) = match errors.len() {
                0 => (f64::NAN, f64::NAN, f64::NAN),
                n => (
                    errors.iter().sum::<f64>() / n as f64,
                    errors.iter().copied().fold(f64::INFINITY, f64::min),
                    errors.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                ),
            };
            FieldAlongRoute {
                field: name.clone(),
                min_distance_m: kept.iter().map(|k| k.2[j]).fold(f64::INFINITY, f64::min),
                error_at_tight_pass_m: tight.2[j] - tight.1,
                near_mean_error_m: mean,
                near_min_error_m: least,
                near_max_error_m: greatest,
            }
        })
        .collect();
    Some(RouteGeometry {
        points: kept.len(),
        near_points: near.len(),
        gt_min_distance_m: tight.1,
        tight_pass_fraction: tight.0,
        fields: rows,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerfsv_collision::GridGeometry;

    /// A sampled field of `f` on a 2 cm grid over [−1, 1]³.
    fn grid(f: impl Fn(Point3<f32>) -> f32) -> SdfGrid {
        let geometry = GridGeometry { origin: Point3::new(-1.0, -1.0, -1.0), cell: 0.02, dims: [101, 101, 101] };
        let mut data = Vec::with_capacity(101 * 101 * 101);
        for k in 0..101 {
            for j in 0..101 {
                for i in 0..101 {
                    data.push(f(geometry.origin + Vector3::new(i as f32, j as f32, k as f32) * geometry.cell));
                }
            }
        }
        SdfGrid { geometry, data }
    }

    /// A sphere of radius 0.3 at the origin, a route passing it at 0.1 m: a field whose sphere is
    /// 1 cm larger errs by −1 cm everywhere (−0.01 at the tight pass, mean, least and greatest),
    /// one shifted 2 cm away from the route errs by +2 cm at the tight pass and less elsewhere.
    #[test]
    fn a_field_with_a_known_error_is_measured_to_it_along_the_route() {
        let sphere = |c: [f32; 3], r: f32| {
            move |p: Point3<f32>| ((p.x - c[0]).powi(2) + (p.y - c[1]).powi(2) + (p.z - c[2]).powi(2)).sqrt() - r
        };
        let gt = grid(sphere([0.0; 3], 0.3));
        let fatter = grid(sphere([0.0; 3], 0.31));
        let away = grid(sphere([0.0, -0.02, 0.0], 0.3));
        let route: Vec<Vector3<f64>> = (0..=160).map(|i| Vector3::new(-0.8 + 0.01 * i as f64, 0.4, 0.0)).collect();
        let fields = [("member 1".to_string(), &fatter), ("member 2".to_string(), &away)];
        let g = route_geometry(&route, &gt, &fields).unwrap();
        assert_eq!(g.points, 161);
        assert!((g.gt_min_distance_m - 0.1).abs() < 2e-3, "{}", g.gt_min_distance_m);
        assert!((g.tight_pass_fraction - 0.5).abs() < 1e-9);
        assert!(g.near_points > 0 && g.near_points < 161, "{}", g.near_points);
        let f = &g.fields[0];
        for e in [f.error_at_tight_pass_m, f.near_mean_error_m, f.near_min_error_m, f.near_max_error_m] {
            assert!((e + 0.01).abs() < 1.5e-3, "{f:?}");
        }
        assert!((f.min_distance_m - 0.09).abs() < 2e-3, "{f:?}");
        let a = &g.fields[1];
        assert!((a.error_at_tight_pass_m - 0.02).abs() < 1.5e-3, "{a:?}");
        assert!(a.near_min_error_m > 0.0 && a.near_mean_error_m < a.error_at_tight_pass_m, "{a:?}");
        // Off every grid: nothing to compare.
        assert!(route_geometry(&[Vector3::new(5.0, 0.0, 0.0)], &gt, &fields).is_none());
    }
}
