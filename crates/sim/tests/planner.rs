//! The planner on analytic signed distance fields and on the default Stonehenge scene.

use std::time::Instant;

use nalgebra::{Point3, Vector3};
use nerfsv_collision::{drone_half_extents, ground_truth_field, ScalarGrid, SdfGrid};
use nerfsv_scene::{Aabb, Scene};
use nerfsv_sim::planner::{plan, required_clearance, PlanError, PlannedPath, PlannerConfig};

const CPM: f32 = 40.0;
/// The planner samples segments every ⅛ cell; between two samples a 1-Lipschitz field can dip
/// by at most half that spacing below the smaller sample.
const SAMPLING_SLACK: f64 = 1.0 / CPM as f64 / 16.0;

/// A room 2 × 1.4 m, 0.8 m high, with the given obstacles' SDF.
fn field(sdf: impl Fn(Point3<f32>) -> f32 + Sync) -> SdfGrid {
    let bounds = Aabb::new(Point3::new(-1.0, -0.7, -0.05), Point3::new(1.0, 0.7, 0.75));
    SdfGrid::from_field(&ScalarGrid::sample(&bounds, CPM, sdf), 0.0, true)
}

/// A vertical cylinder of radius `r` around (cx, cy), from the floor up past the band.
fn cylinder(cx: f32, cy: f32, r: f32) -> impl Fn(Point3<f32>) -> f32 + Sync {
    move |p| ((p.x - cx).powi(2) + (p.y - cy).powi(2)).sqrt() - r
}

fn required() -> f64 {
    required_clearance(drone_half_extents(), PlannerConfig::default().margin)
}

/// The smallest trilinear field value along the path, sampled every millimetre.
fn min_clearance(field: &SdfGrid, path: &PlannedPath) -> f64 {
    let len = path.length();
    let n = (len / 1e-3).ceil() as usize;
    (0..=n)
        .map(|i| {
            let p = path.point_at(len * i as f64 / n as f64);
            field.distance(Point3::new(p.x as f32, p.y as f32, p.z as f32)).in_grid().expect("path stays in the grid")
                as f64
        })
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn required_clearance_is_the_half_diagonal_plus_margin() {
    let r = required_clearance(drone_half_extents(), 0.03);
    assert!((r - (0.05f64 * 0.05 * 2.0 + 0.02 * 0.02).sqrt() - 0.03).abs() < 1e-7, "{r}");
    assert!((r - 0.1035).abs() < 1e-3);
}

#[test]
fn nothing_in_the_way_gives_the_straight_segment() {
    let f = field(cylinder(0.0, 0.6, 0.05));
    let (s, g) = (Vector3::new(-0.7, -0.2, 0.2), Vector3::new(0.7, 0.1, 0.3));
    let path = plan(&f, s, g, drone_half_extents(), &PlannerConfig::default()).unwrap();
    assert_eq!(path.points, vec![s, g]);
}

#[test]
fn a_cylinder_between_start_and_goal_is_avoided_with_the_required_clearance_everywhere() {
    let f = field(cylinder(0.0, 0.02, 0.15));
    let (s, g) = (Vector3::new(-0.7, 0.0, 0.25), Vector3::new(0.7, 0.0, 0.25));
    let cfg = PlannerConfig::default();
    let path = plan(&f, s, g, drone_half_extents(), &cfg).unwrap();
    assert_eq!(path.points.first(), Some(&s));
    assert_eq!(path.points.last(), Some(&g));
    let clearance = min_clearance(&f, &path);
    assert!(clearance >= required() - SAMPLING_SLACK, "min clearance {clearance:.4} m, required {:.4} m", required());
    // Around, not over: the band stops at 0.5 m, and the detour is short (≈ the arc around the
    // cylinder at the clearance radius: 1.4 m straight becomes about 1.5 m).
    assert!(path.points.iter().all(|p| p.z >= cfg.altitude[0] && p.z <= cfg.altitude[1]));
    let len = path.length();
    assert!(len > 1.42 && len < 1.6, "length {len}");
    assert!(path.points.len() <= 6, "shortcutting leaves a few vertices: {:?}", path.points);
    eprintln!("cylinder: {} vertices, length {len:.3} m, min clearance {clearance:.4} m", path.points.len());
}

#[test]
fn planning_is_deterministic() {
    let f = field(|p| cylinder(0.0, 0.0, 0.12)(p).min(cylinder(0.35, -0.25, 0.1)(p)));
    let (s, g) = (Vector3::new(-0.7, 0.05, 0.2), Vector3::new(0.75, -0.3, 0.35));
    let a = plan(&f, s, g, drone_half_extents(), &PlannerConfig::default()).unwrap();
    let b = plan(&f, s, g, drone_half_extents(), &PlannerConfig::default()).unwrap();
    assert_eq!(a, b);
    assert!(a.points.len() > 2);
}

#[test]
fn a_start_inside_geometry_is_blocked_and_named() {
    let f = field(cylinder(-0.5, 0.0, 0.1));
    let e =
        plan(&f, Vector3::new(-0.45, 0.0, 0.2), Vector3::new(0.5, 0.0, 0.2), drone_half_extents(), &Default::default())
            .unwrap_err();
    match &e {
        PlanError::Blocked { which, distance, required: r, .. } => {
            assert_eq!(*which, "start");
            assert!(*distance < 0.0 && (*r - required()).abs() < 1e-12, "{e:?}");
        }
        other => panic!("expected Blocked, got {other:?}"),
    }
    let msg = e.to_string();
    assert!(msg.starts_with("start (-0.45, 0.00, 0.20) is inside geometry"), "{msg}");
    assert!(msg.ends_with("the body needs 0.103 m"), "{msg}");
    // Close but outside: the message gives the distance.
    let e =
        plan(&f, Vector3::new(-0.37, 0.0, 0.2), Vector3::new(0.5, 0.0, 0.2), drone_half_extents(), &Default::default())
            .unwrap_err();
    assert!(e.to_string().contains("is 0.03"), "{e}");
}

#[test]
fn a_goal_outside_the_grid_or_the_band_is_refused() {
    let f = field(|p| p.z + 1.0);
    let s = Vector3::new(0.0, 0.0, 0.2);
    let e = plan(&f, s, Vector3::new(1.5, 0.0, 0.2), drone_half_extents(), &Default::default()).unwrap_err();
    assert!(matches!(e, PlanError::OutsideGrid { which: "goal", .. }), "{e:?}");
    assert!(e.to_string().starts_with("goal (1.50, 0.00, 0.20) is outside the collision grid"), "{e}");
    let e = plan(&f, s, Vector3::new(0.5, 0.0, 0.6), drone_half_extents(), &Default::default()).unwrap_err();
    assert!(matches!(e, PlanError::OutsideAltitude { which: "goal", .. }), "{e:?}");
    assert_eq!(e.to_string(), "goal is at altitude 0.600 m, outside the flight band [0.15, 0.5] m");
    let bad = PlannerConfig { margin: f64::NAN, ..Default::default() };
    let e = plan(&f, s, s, drone_half_extents(), &bad).unwrap_err();
    assert!(e.to_string().starts_with("planner.margin:"), "{e}");
}

#[test]
fn a_closed_wall_leaves_no_path() {
    // A wall across the room at x = 0, 0.1 m thick, floor to ceiling.
    let f = field(|p| p.x.abs() - 0.05);
    let e =
        plan(&f, Vector3::new(-0.5, 0.0, 0.3), Vector3::new(0.5, 0.0, 0.3), drone_half_extents(), &Default::default())
            .unwrap_err();
    assert!(matches!(e, PlanError::NoPath { .. }), "{e:?}");
    assert_eq!(
        e.to_string(),
        "no path from (-0.50, 0.00, 0.30) to (0.50, 0.00, 0.30) keeps 0.103 m from geometry inside the altitude band"
    );
    // A door 0.32 m wide (the body needs 2 × 0.1035 m) opens it, and the path goes through it.
    let f = field(|p| (p.x.abs() - 0.05).max(0.16 - p.y.abs()));
    let (s, g) = (Vector3::new(-0.5, 0.3, 0.3), Vector3::new(0.5, 0.3, 0.3));
    let path = plan(&f, s, g, drone_half_extents(), &Default::default()).unwrap();
    let through = path.point_at(path.length() * 0.5);
    assert!(through.y.abs() < 0.16 - 0.1, "{through:?}");
    assert!(min_clearance(&f, &path) >= required() - SAMPLING_SLACK);
    // A door 0.2 m wide does not.
    let f = field(|p| (p.x.abs() - 0.05).max(0.1 - p.y.abs()));
    assert!(matches!(plan(&f, s, g, drone_half_extents(), &Default::default()), Err(PlanError::NoPath { .. })));
}

#[test]
fn the_default_flight_passes_the_monolith_on_the_stonehenge_field() {
    let scene = Scene::stonehenge();
    let (built, _) = ground_truth_field(&scene, 40.0).unwrap();
    let f = &built.sdf;
    let (s, g) = (Vector3::new(0.39, -0.67, 0.2), Vector3::new(-0.4, 0.55, 0.16));
    let cfg = PlannerConfig::default();
    let t0 = Instant::now();
    let path = plan(f, s, g, drone_half_extents(), &cfg).unwrap();
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let clearance = min_clearance(f, &path);
    eprintln!("default flight: planned in {ms:.1} ms, length {:.3} m, min clearance {clearance:.4} m", path.length());
    for p in &path.points {
        eprintln!("  ({:.4}, {:.4}, {:.4})", p.x, p.y, p.z);
    }
    assert!(path.points.len() >= 3, "the straight line crosses the monolith");
    assert!(clearance >= required() - SAMPLING_SLACK, "min clearance {clearance:.4} m");
    // The path passes beside the monolith (centre at the origin), not through the outer ring.
    let closest =
        (0..=100).map(|i| path.point_at(path.length() * i as f64 / 100.0).xy().norm()).fold(f64::MAX, f64::min);
    assert!(closest < 0.35, "closest approach to the monolith {closest:.3} m");
    assert!(path.length() < 1.8, "length {}", path.length());
}
