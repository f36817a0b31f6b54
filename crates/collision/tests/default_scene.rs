//! The collision pipeline on the default Stonehenge scene against its analytic SDF.

use nalgebra::{Point3, Rotation3, Vector3};
use nerfsv_collision::{drone_half_extents, BoxQuery, GridGeometry, ScalarGrid, SdfGrid};
use nerfsv_scene::Scene;

const CELL: f32 = 0.025;

fn field(scene: &Scene) -> SdfGrid {
    let mut bounds = scene.bounds().expanded(0.1);
    bounds.max.z = 1.0;
    let geometry = GridGeometry::covering(&bounds, 40.0).unwrap();
    let samples = ScalarGrid::sample_geometry(geometry, |p| scene.distance(&p));
    SdfGrid::from_field(&samples, 0.0, true)
}

/// Deterministic points in the scene's flight region.
fn points(n: u32) -> impl Iterator<Item = Point3<f32>> {
    (0..n).map(|k| {
        let h =
            |m: u32| nerfsv_scene::texture::value_noise(k as f32 * 0.917 + 0.3, m as f32 * 7.31 + 0.1, 0.77 * k as f32);
        let (r, a) = (1.75 * h(1).sqrt(), std::f32::consts::TAU * h(2));
        Point3::new(r * a.cos(), r * a.sin(), -0.05 + 0.9 * h(3))
    })
}

#[test]
fn stonehenge_field_is_within_one_cell_of_the_analytic_sdf_and_signed_right() {
    let scene = Scene::stonehenge();
    let sdf = field(&scene);
    let (mut outside, mut inside) = (0, 0);
    for p in points(20_000) {
        let exact = scene.distance(&p);
        let grid = sdf.distance(p).in_grid().expect("inside the grid");
        if exact > 0.5 * CELL {
            assert!((grid - exact).abs() <= CELL, "at {p}: grid {grid} vs analytic {exact}");
            outside += 1;
        }
        if exact.abs() > CELL {
            assert_eq!(grid > 0.0, exact > 0.0, "sign at {p}: grid {grid} vs analytic {exact}");
        }
        if exact < -CELL {
            inside += 1;
        }
    }
    assert!(outside > 10_000 && inside > 100, "outside {outside}, inside {inside}");
}

#[test]
fn drone_box_clearance_matches_brute_force_on_the_analytic_scene() {
    let scene = Scene::stonehenge();
    let sdf = field(&scene);
    let half = drone_half_extents();
    let mut near = 0;
    for (k, c) in points(400).enumerate() {
        let c = Point3::new(c.x, c.y, 0.1 + 0.4 * ((k as f32 * 0.37).fract()));
        let rot = Rotation3::from_euler_angles(0.3 * (k as f32).sin(), 0.2 * (k as f32 * 1.3).cos(), k as f32);
        // Brute force: the analytic SDF's minimum over a dense lattice filling the box.
        let n = 12;
        let mut brute = f32::INFINITY;
        for i in 0..=n {
            for j in 0..=n {
                for l in 0..=n {
                    let u = Vector3::new(i as f32, j as f32, l as f32) / n as f32 * 2.0 - Vector3::repeat(1.0);
                    brute = brute.min(scene.distance(&(c + rot * half.component_mul(&u))));
                }
            }
        }
        let q = sdf.box_query(c, &rot, half);
        let got = q.min_sdf().expect("in grid");
        assert!((got - brute).abs() <= CELL, "box {k} at {c}: query {got} vs brute force {brute}");
        if brute <= -CELL {
            assert!(matches!(q, BoxQuery::Touching { .. }), "box {k} penetrates by {brute} but query says {q:?}");
        }
        if brute >= CELL {
            assert!(matches!(q, BoxQuery::Clear { .. }), "box {k} is {brute} clear but query says {q:?}");
        }
        if brute < 0.1 {
            near += 1;
        }
    }
    assert!(near > 30, "only {near} boxes near geometry");
}
