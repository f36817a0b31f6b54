//! The collision pipeline on the default Stonehenge scene against its analytic SDF.

use std::collections::HashMap;

use nalgebra::{Point3, Rotation3, Vector3};
use nerfsv_collision::{
    drone_half_extents, field_bounds, ground_truth_field, scene_field, BoxQuery, GridGeometry, SdfGrid,
};
use nerfsv_scene::Scene;

const CELL: f32 = 0.025;

fn field(scene: &Scene) -> SdfGrid {
    let geometry = GridGeometry::covering(&field_bounds(&scene.bounds()), 40.0).unwrap();
    scene_field(scene, geometry).1
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

#[test]
fn nodes_inside_the_solid_read_negative_including_where_stones_stand_on_the_ground() {
    // Stones stand on the ground: a stone's bottom face and the ground's top face coincide at
    // z = 0, where the analytic SDF of the union is exactly 0 although there is solid above and
    // below. A node is inside the solid when it and its 26 neighbour nodes lie in the closed
    // solid (analytic distance ≤ 0); every such node must read a negative signed distance.
    let scene = Scene::stonehenge();
    let geometry = GridGeometry::covering(&field_bounds(&scene.bounds()), 40.0).unwrap();
    let (exact, sdf) = scene_field(&scene, geometry);
    let [nx, ny, nz] = geometry.dims;
    let (mut inside, mut on_contact_plane, mut wrong) = (0, 0, Vec::new());
    for k in 1..nz - 1 {
        for j in 1..ny - 1 {
            for i in 1..nx - 1 {
                let solid = (0..27).all(|n| {
                    let (di, dj, dk) = (n % 3, (n / 3) % 3, n / 9);
                    exact.get(i + di - 1, j + dj - 1, k + dk - 1) <= 0.0
                });
                if !solid {
                    continue;
                }
                inside += 1;
                on_contact_plane += (exact.get(i, j, k) == 0.0) as usize;
                if sdf.get(i, j, k) >= 0.0 {
                    wrong.push(([i, j, k], sdf.get(i, j, k)));
                }
            }
        }
    }
    assert!(inside > 50_000 && on_contact_plane > 150, "inside {inside}, on the contact plane {on_contact_plane}");
    assert!(
        wrong.is_empty(),
        "{} of {inside} inside nodes read ≥ 0, e.g. {:?}",
        wrong.len(),
        &wrong[..wrong.len().min(5)]
    );
}

#[test]
fn ground_truth_mesh_is_closed_without_degenerate_or_doubled_faces() {
    let (built, errors) = ground_truth_field(&Scene::stonehenge(), 40.0).unwrap();
    let m = &built.mesh;
    assert!(m.triangles.len() > 50_000);
    assert!(m.is_closed(), "the ground-truth surface must be closed and consistently wound");
    let key = |i: u32| m.vertices[i as usize].coords.map(f32::to_bits);
    let mut faces: HashMap<[[u32; 3]; 3], usize> = HashMap::new();
    for t in &m.triangles {
        assert!(t[0] != t[1] && t[1] != t[2] && t[0] != t[2], "triangle with a repeated vertex {t:?}");
        let [a, b, c] = t.map(|i| m.vertices[i as usize].coords.cast::<f64>());
        assert!((b - a).cross(&(c - a)).norm() > 0.0, "zero-area triangle {t:?}");
        // Faces by vertex position, so that coincident faces with distinct vertices count too.
        let mut f = t.map(|i| key(i).into());
        f.sort_unstable();
        *faces.entry(f).or_default() += 1;
    }
    let doubled = faces.values().filter(|&&n| n > 1).count();
    assert_eq!(doubled, 0, "{doubled} faces occur more than once (coincident opposite faces)");
    // The grid field against the analytic SDF near surfaces: a fraction of a cell.
    assert!(errors.nodes > 100_000 && errors.mean < 0.1 * CELL as f64 && errors.p95 < 0.5 * CELL, "{errors:?}");
}

/// Where a stone stands on the ground, the analytic distance is exactly 0 on the contact plane
/// and the solid continues above and below: no node of such a plane may read ≥ 0 between inside
/// nodes above and below it (five did, around (−1.66, −0.64, 0) m, where the fallen lintel
/// overhangs the ground disc's rim). Real gaps thinner than a cell (a lintel a few millimetres
/// above a shorter upright) have a positive analytic distance and are not contact planes.
#[test]
fn no_node_of_the_default_field_is_outside_between_solid_above_and_below() {
    let scene = Scene::stonehenge();
    let (built, _) = ground_truth_field(&scene, 40.0).unwrap();
    let (sdf, g) = (&built.sdf, built.sdf.geometry);
    let mut seams = Vec::new();
    let mut contact = 0;
    for k in 1..g.dims[2] - 1 {
        for j in 0..g.dims[1] {
            for i in 0..g.dims[0] {
                let v = |k| sdf.data[g.index(i, j, k)];
                // On a contact plane (analytic distance exactly 0) between solid above and below.
                if v(k + 1) < 0.0 && v(k - 1) < 0.0 && scene.distance(&g.position_of(i, j, k)) == 0.0 {
                    contact += 1;
                    if v(k) >= 0.0 {
                        seams.push((i, j, k, v(k)));
                    }
                }
            }
        }
    }
    assert!(contact > 100, "only {contact} nodes on a contact plane: the case tests nothing");
    assert!(seams.is_empty(), "nodes outside between solid above and below: {seams:?}");
}

/// Two boxes touching on the plane z = 4, one contact node nudged to float noise (+1e-9) and
/// the node beside it therefore next to a strictly outside value: the repair makes the seam
/// node inside (the larger of its neighbours' values above and below), leaves the noisy node,
/// whose neighbours above and below are on the boxes' faces, and every other value alone.
#[test]
fn contact_plane_zeros_between_solid_take_their_neighbours_value() {
    use nerfsv_collision::{classify_nodes, repair_contact_planes, ScalarGrid};
    let g = GridGeometry::new(Point3::origin(), 1.0, [8, 8, 9]).unwrap();
    let boxed = |p: Point3<f32>, lo: [f32; 3], hi: [f32; 3]| {
        let q: [f32; 3] = std::array::from_fn(|a| (p[a] - 0.5 * (lo[a] + hi[a])).abs() - 0.5 * (hi[a] - lo[a]));
        q.iter().map(|v| v.max(0.0).powi(2)).sum::<f32>().sqrt() + q[0].max(q[1]).max(q[2]).min(0.0)
    };
    let mut field = ScalarGrid::sample_geometry(g, |p| {
        boxed(p, [2.0, 2.0, 1.0], [5.0, 5.0, 4.0]).min(boxed(p, [2.0, 2.0, 4.0], [5.0, 5.0, 7.0]))
    });
    field.data[g.index(2, 3, 4)] = 1e-9;
    assert!(!classify_nodes(&field, 0.0, true)[g.index(3, 3, 4)], "the seam node is outside before the repair");
    let repaired = repair_contact_planes(&field);
    let (above, below) = (field.get(3, 3, 5), field.get(3, 3, 3));
    assert_eq!(repaired.get(3, 3, 4), above.max(below));
    assert!(classify_nodes(&repaired, 0.0, true)[g.index(3, 3, 4)]);
    let changed: Vec<usize> = (0..g.len()).filter(|&i| repaired.data[i] != field.data[i]).collect();
    // The interior contact nodes {3, 4}² at z = 4, nothing else.
    assert_eq!(changed.len(), 4, "{changed:?}");
    assert!(changed.iter().all(|&i| g.coords(i)[2] == 4));
}
