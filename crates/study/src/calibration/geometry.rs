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

/// A near point whose ground truth's distance grows upward more steeply than this (the cosine of
/// the nearest surface's normal from the vertical) has the ground below it, not an obstacle
/// beside it. A route flown at a fixed altitude is "near" the ground everywhere, and a NeRF's
/// ground, seen at grazing angles, errs otherwise than its obstacles: the two are reported apart.
pub const GROUND_NORMAL_Z: f32 = std::f32::consts::FRAC_1_SQRT_2;

/// Spacing of the compared points along the path (m).
pub const SPACING_M: f64 = 0.01;

/// Each field's signed distance along the route against the ground truth's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RouteGeometry {
    /// Points compared: the planned path every [`SPACING_M`], the body's centre.
    pub points: usize,
    /// Of them, the ones within [`NEAR_M`] of the ground truth's geometry beside the route (an
    /// obstacle's surface: the nearest surface's normal within 45° of horizontal).
    pub near_points: usize,
    /// The ones within [`NEAR_M`] of the ground below them (the normal within 45° of vertical).
    pub ground_points: usize,
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
    /// Mean, least and greatest error over the near points beside the route (m); `None`
    /// without such points.
    pub near_mean_error_m: Option<f64>,
    pub near_min_error_m: Option<f64>,
    pub near_max_error_m: Option<f64>,
    /// Mean error over the points near the ground below (m); `None` without such points.
    pub ground_mean_error_m: Option<f64>,
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
    let at = |field: &SdfGrid, q: Point3<f32>| field.distance(q).in_grid().map(f64::from);
    // Each kept point's fraction along the route, the ground truth's distance, whether the
    // nearest real surface is the ground below, and each field's distance.
    let last = points.len().saturating_sub(1).max(1) as f64;
    let kept: Vec<Kept> = points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let q = Point3::new(p.x as f32, p.y as f32, p.z as f32);
            let g = at(gt, q)?;
            let ground =
                gt.gradient(q).in_grid().and_then(|n| n.try_normalize(1e-6)).is_some_and(|n| n.z > GROUND_NORMAL_Z);
            let f: Option<Vec<f64>> = fields.iter().map(|(_, field)| at(field, q)).collect();
            Some(Kept { fraction: i as f64 / last, gt: g, ground, fields: f? })
        })
        .collect();
    let tight = kept.iter().min_by(|a, b| a.gt.total_cmp(&b.gt))?;
    let near: Vec<&Kept> = kept.iter().filter(|k| k.gt < NEAR_M && !k.ground).collect();
    let ground: Vec<&Kept> = kept.iter().filter(|k| k.gt < NEAR_M && k.ground).collect();
    let rows = fields
        .iter()
        .enumerate()
        .map(|(j, (name, _))| {
            let errors: Vec<f64> = near.iter().map(|k| k.fields[j] - k.gt).collect();
            let ground_errors: Vec<f64> = ground.iter().map(|k| k.fields[j] - k.gt).collect();
            let mean = |e: &[f64]| (!e.is_empty()).then(|| e.iter().sum::<f64>() / e.len() as f64);
            FieldAlongRoute {
                field: name.clone(),
                min_distance_m: kept.iter().map(|k| k.fields[j]).fold(f64::INFINITY, f64::min),
                error_at_tight_pass_m: tight.fields[j] - tight.gt,
                near_mean_error_m: mean(&errors),
                near_min_error_m: errors.iter().copied().reduce(f64::min),
                near_max_error_m: errors.iter().copied().reduce(f64::max),
                ground_mean_error_m: mean(&ground_errors),
            }
        })
        .collect();
    Some(RouteGeometry {
        points: kept.len(),
        near_points: near.len(),
        ground_points: ground.len(),
        gt_min_distance_m: tight.gt,
        tight_pass_fraction: tight.fraction,
        fields: rows,
    })
}

/// A compared point of the route.
struct Kept {
    fraction: f64,
    gt: f64,
    ground: bool,
    fields: Vec<f64>,
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

    /// A sphere of radius 0.3 at the origin over the ground at z = −0.2, a route at z = 0 passing
    /// the sphere at 0.1 m: a field whose sphere is 1 cm larger and ground 1 cm higher errs by
    /// −1 cm everywhere (at the tight pass, beside the route and below it); one whose sphere is
    /// shifted 2 cm away from the route errs by +2 cm at the tight pass, less elsewhere, and not
    /// at all on the ground; one whose ground alone is 1 cm higher errs only below the route.
    #[test]
    fn a_field_with_a_known_error_is_measured_to_it_along_the_route() {
        let world = |c: [f32; 3], r: f32, ground: f32| {
            move |p: Point3<f32>| {
                (((p.x - c[0]).powi(2) + (p.y - c[1]).powi(2) + (p.z - c[2]).powi(2)).sqrt() - r).min(p.z - ground)
            }
        };
        let gt = grid(world([0.0; 3], 0.3, -0.2));
        let fatter = grid(world([0.0; 3], 0.31, -0.19));
        let away = grid(world([0.0, -0.02, 0.0], 0.3, -0.2));
        let ground_up = grid(world([0.0; 3], 0.3, -0.19));
        let route: Vec<Vector3<f64>> = (0..=160).map(|i| Vector3::new(-0.8 + 0.01 * i as f64, 0.4, 0.0)).collect();
        let fields =
            [("member 1".to_string(), &fatter), ("member 2".to_string(), &away), ("member 3".to_string(), &ground_up)];
        let g = route_geometry(&route, &gt, &fields).unwrap();
        assert_eq!(g.points, 161);
        assert!((g.gt_min_distance_m - 0.1).abs() < 2e-3, "{}", g.gt_min_distance_m);
        assert!((g.tight_pass_fraction - 0.5).abs() < 1e-9);
        // Beside the sphere near the middle, the ground below everywhere else.
        assert!(g.near_points > 10 && g.ground_points > 10, "{g:?}");
        assert_eq!(g.near_points + g.ground_points, 161);
        let some = |e: Option<f64>| e.expect("points beside the route and above the ground");
        let f = &g.fields[0];
        for e in [
            f.error_at_tight_pass_m,
            some(f.near_mean_error_m),
            some(f.near_min_error_m),
            some(f.near_max_error_m),
            some(f.ground_mean_error_m),
        ] {
            assert!((e + 0.01).abs() < 1.5e-3, "{f:?}");
        }
        assert!((f.min_distance_m - 0.09).abs() < 2e-3, "{f:?}");
        let a = &g.fields[1];
        assert!((a.error_at_tight_pass_m - 0.02).abs() < 1.5e-3, "{a:?}");
        assert!(some(a.near_min_error_m) > 0.0 && some(a.near_mean_error_m) < a.error_at_tight_pass_m, "{a:?}");
        assert!(some(a.ground_mean_error_m).abs() < 1e-3, "{a:?}");
        let u = &g.fields[2];
        assert!(u.error_at_tight_pass_m.abs() < 1e-3 && some(u.near_mean_error_m).abs() < 2e-3, "{u:?}");
        assert!((some(u.ground_mean_error_m) + 0.01).abs() < 1.5e-3, "{u:?}");
        // Off every grid: nothing to compare.
        assert!(route_geometry(&[Vector3::new(5.0, 0.0, 0.0)], &gt, &fields).is_none());
    }
}
