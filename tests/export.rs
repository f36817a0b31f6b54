//! `nerfsv export` on a tiny run folder written by hand (the files the export reads, in the
//! formats the stages write them), read back with the `gltf` crate; and its refusals.

mod common;

use std::path::Path;

use common::{nerfsv, s};
use gltf::mesh::Mode;
use nalgebra::Point3;
use nerfsv_scene::mesh::{ply_bytes, TriangleMesh};
use nerfsv_validation::{write_csv_file, Label, RolloutRecord, Trajectory};

/// A closed tetrahedron around `(c, c, c)`.
fn tetrahedron(c: f32) -> TriangleMesh {
    let p = |x: f32, y: f32, z: f32| Point3::new(c + x, c + y, c + z);
    TriangleMesh::new(
        vec![p(0.0, 0.0, 0.0), p(0.2, 0.0, 0.0), p(0.0, 0.2, 0.0), p(0.0, 0.0, 0.2)],
        vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    )
}

/// A rollout of three steps at `positions`; a failure crashes at step 1 (its step 2 is kept but
/// does not count).
fn rollout(sampler: Label, population: usize, index: usize, failed: bool, positions: [[f64; 3]; 3]) -> RolloutRecord {
    RolloutRecord {
        sampler,
        population,
        index,
        seed: 7 + index as u64,
        disturbances: Trajectory::from_rows(12, [[0.0; 12]; 3]).unwrap(),
        step_log_p: vec![1.0; 3],
        step_log_q: vec![1.0; 3],
        score: if failed { -0.01 } else { 0.05 },
        step_scores: if failed { vec![0.05, -0.01, f64::NAN] } else { vec![0.05; 3] },
        step_positions: positions.to_vec(),
        step_attitudes: vec![[0.0; 3]; 3],
        collision_step: failed.then_some(1),
        failed,
        ..Default::default()
    }
    .recounted()
}

/// A flight CSV with the pose columns of `nerfsv_sim::trajectory_csv` (level attitudes).
fn flight_csv(path: &Path, truth: &[[f64; 3]], estimate: &[[f64; 3]]) {
    let mut text = String::from(
        "step,substep,time_s,true_x,true_y,true_z,true_qw,true_qx,true_qy,true_qz,\
         est_x,est_y,est_z,est_qw,est_qx,est_qy,est_qz,clearance_m,collided\n",
    );
    for (k, (t, e)) in truth.iter().zip(estimate).enumerate() {
        text.push_str(&format!(
            "0,{k},{},{},{},{},1,0,0,0,{},{},{},1,0,0,0,0.1,0\n",
            k as f64 * 0.1,
            t[0],
            t[1],
            t[2],
            e[0],
            e[1],
            e[2]
        ));
    }
    std::fs::write(path, text).unwrap();
}

/// The files `nerfsv export` reads of a run folder, with a Monte Carlo search in NeRF-sim
/// (rollout 0/1 its most likely failure, 0/2 another failure, 0/0 no failure), a CEM failure,
/// and the searches replayed in GT-sim.
fn tiny_run(root: &Path) {
    for dir in ["collision", "nerf_collision", "flight", "stress"] {
        std::fs::create_dir_all(root.join(dir)).unwrap();
    }
    std::fs::write(root.join("summary.json"), format!("{{\"run\": {:?}}}", s(root))).unwrap();
    std::fs::write(root.join("collision/gt_mesh.ply"), ply_bytes(&tetrahedron(0.0))).unwrap();
    std::fs::write(root.join("nerf_collision/nerf_mesh.ply"), ply_bytes(&tetrahedron(0.01))).unwrap();
    let route = r#"{"key": "k", "seconds": 0.1, "figures": {"path_length_m": 1.0, "path_vertices": [],
        "waypoints": [[0.0, 0.0, 0.2], [0.5, 0.1, 0.2], [1.0, 0.5, 0.3]], "flights": []}}"#;
    std::fs::write(root.join("flight/stage.json"), route).unwrap();
    let stress = r#"{"key": "k", "seconds": 1.0, "figures": {"world": "nerf", "replay_world": "gt",
        "samplers": [
          {"sampler": "mc", "most_likely_failure": {"sampler": "mc", "population": 0, "index": 1,
            "seed": 8, "log_likelihood": 3.0, "collision_step": 2, "min_clearance_m": -0.01,
            "replay_collided": false, "replay_min_clearance_m": 0.02}},
          {"sampler": "cem", "most_likely_failure": null}]}}"#;
    std::fs::write(root.join("stress/stage.json"), stress).unwrap();
    let p = |x: f64| [[x, 0.0, 0.2], [x + 0.1, 0.1, 0.2], [x + 0.2, 0.2, 0.2]];
    let searched = [
        rollout(Label::Mc, 0, 0, false, p(0.0)),
        rollout(Label::Mc, 0, 1, true, p(1.0)),
        rollout(Label::Mc, 0, 2, true, p(2.0)),
        rollout(Label::Cem, 0, 0, true, p(3.0)),
    ];
    write_csv_file(&root.join("stress/rollouts.csv"), &searched).unwrap();
    let replayed = [rollout(Label::Mc, 0, 1, false, p(1.5)), rollout(Label::Mc, 0, 2, true, p(2.5))];
    write_csv_file(&root.join("stress/replay_gt.csv"), &replayed).unwrap();
    let truth = [[0.1, 0.2, 0.3], [0.2, 0.3, 0.3], [0.3, 0.4, 0.25]];
    let estimate = [[0.11, 0.2, 0.3], [0.22, 0.31, 0.3], [0.33, 0.42, 0.26]];
    flight_csv(&root.join("stress/most_likely_failure_mc_nerf.csv"), &truth, &estimate);
    flight_csv(&root.join("stress/most_likely_failure_mc_gt.csv"), &truth[..2], &estimate[..2]);
}

/// The node names of a GLB's JSON chunk, in node order (the workspace's `gltf` is built
/// without node names).
fn node_names(bytes: &[u8]) -> Vec<String> {
    let len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let doc: serde_json::Value = serde_json::from_slice(&bytes[20..20 + len]).unwrap();
    doc["nodes"].as_array().unwrap().iter().map(|n| n["name"].as_str().unwrap().to_owned()).collect()
}

/// nerfsv's z-up point as glTF's y-up one.
fn y_up(p: [f64; 3]) -> [f32; 3] {
    [p[0] as f32, p[2] as f32, -p[1] as f32]
}

#[test]
fn export_writes_the_meshes_route_and_failures_of_a_run_as_a_glb() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    tiny_run(&run);
    let out = dir.path().join("failures.glb");
    let (ok, stdout, err) = nerfsv(&["export", s(&run), "--out", s(&out), "--json"]);
    assert!(ok, "{err}");
    let figures: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(figures["failing_rollouts"], 3, "{figures}"); // mc 0/2, cem 0/0; mc 0/2 in GT-sim
    assert_eq!(figures["failing_rollouts_exported"], 3, "{figures}");
    assert_eq!(figures["most_likely_failure_flights"], 2, "{figures}");

    let bytes = std::fs::read(&out).unwrap();
    let glb = gltf::Gltf::from_slice(&bytes).expect("the gltf crate reads the export");
    let blob = glb.blob.as_deref().unwrap();
    let names = node_names(&bytes);
    let expected = [
        "GT mesh",
        "NeRF mesh",
        "route (planned waypoints)",
        "mc NeRF-sim rollout 0/1 most likely failure true",
        "mc NeRF-sim rollout 0/1 most likely failure estimate",
        "mc GT-sim rollout 0/1 most likely failure (no crash here) true",
        "mc GT-sim rollout 0/1 most likely failure (no crash here) estimate",
        "mc NeRF-sim rollout 0/2 true",
        "cem NeRF-sim rollout 0/0 true",
        "mc GT-sim rollout 0/2 true",
        "meshes",
        "route",
        "most likely failures",
        "failing rollouts, NeRF-sim",
        "failing rollouts, GT-sim",
    ];
    assert_eq!(names, expected);
    assert_eq!(figures["nodes"], expected.len());

    let positions = |node: usize| -> (Mode, Vec<[f32; 3]>, Option<Vec<u32>>) {
        let mesh = glb.document.nodes().nth(node).unwrap().mesh().unwrap();
        let prim = mesh.primitives().next().unwrap();
        let reader = prim.reader(|_| Some(blob));
        let indices = reader.read_indices().map(|i| i.into_u32().collect());
        (prim.mode(), reader.read_positions().unwrap().collect(), indices)
    };
    let (mode, gt, indices) = positions(0);
    assert_eq!(mode, Mode::Triangles);
    assert_eq!(gt, tetrahedron(0.0).positions.iter().map(|p| [p.x, p.z, -p.y]).collect::<Vec<_>>());
    assert_eq!(indices.unwrap(), [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3]);
    let (mode, route, _) = positions(2);
    assert_eq!(mode, Mode::LineStrip);
    assert_eq!(route, [[0.0, 0.2, 0.0], [0.5, 0.2, -0.1], [1.0, 0.3, -0.5]]);
    let (_, estimate, _) = positions(4);
    assert_eq!(estimate[2], y_up([0.33, 0.42, 0.26]));
    assert_eq!(positions(6).1.len(), 2);
    // A failure's track ends at its crash step (the step after it is not drawn).
    let (mode, track, indices) = positions(7);
    assert_eq!((mode, indices), (Mode::LineStrip, None));
    assert_eq!(track, [y_up([2.0, 0.0, 0.2]), y_up([2.1, 0.1, 0.2])]);
    let colour = |node: usize| {
        let mesh = glb.document.nodes().nth(node).unwrap().mesh().unwrap();
        mesh.primitives().next().unwrap().material().pbr_metallic_roughness().base_color_factor()
    };
    let (red, orange) = (colour(3), colour(4));
    assert!(red[0] > 0.8 && red[1] < 0.1 && orange[0] > 0.9 && orange[1] > 0.3, "{red:?} {orange:?}");
    assert!(colour(1)[3] < 1.0, "the NeRF mesh is translucent");
    assert!(colour(2)[2] > 0.8, "the route is blue");

    // --max-tracks caps the failing rollouts, in turn from each sampler and world; the file it
    // wrote before is nerfsv's and is replaced.
    let (ok, _, err) = nerfsv(&["export", s(&run), "--out", s(&out), "--max-tracks", "2"]);
    assert!(ok, "{err}");
    assert!(err.contains("2 of 3 failing rollouts exported (--max-tracks 2)"), "{err}");
    let names = node_names(&std::fs::read(&out).unwrap());
    assert!(names.contains(&"mc NeRF-sim rollout 0/2 true".to_owned()), "{names:?}");
    assert!(names.contains(&"cem NeRF-sim rollout 0/0 true".to_owned()), "{names:?}");
    assert!(!names.iter().any(|n| n.starts_with("mc GT-sim rollout 0/2")), "{names:?}");
}

#[test]
fn export_refuses_a_missing_run_folder_and_a_file_it_did_not_write() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no-such-run");
    let out = dir.path().join("failures.glb");
    let (ok, _, err) = nerfsv(&["export", s(&missing), "--out", s(&out)]);
    assert!(!ok);
    assert!(err.contains(s(&missing)) && err.contains("not a run folder"), "{err}");
    assert!(!out.exists());

    let run = dir.path().join("run");
    tiny_run(&run);
    std::fs::write(&out, b"glTF from another program").unwrap();
    let (ok, _, err) = nerfsv(&["export", s(&run), "--out", s(&out)]);
    assert!(!ok);
    assert!(err.contains("--out") && err.contains("nerfsv did not write it"), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), b"glTF from another program");
    let inside = run.join("failures.glb");
    let (ok, _, err) = nerfsv(&["export", s(&run), "--out", s(&inside)]);
    assert!(!ok && err.contains("nerfsv never writes over what it reads"), "{err}");
}
