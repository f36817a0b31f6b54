mod common;

use common::{tiny_config, tiny_split, tiny_train_config};
use nerfsv_nerf::{evaluate, EvalOptions, NerfError, Trainer};

fn train_steps(t: &mut Trainer, n: usize) {
    for _ in 0..n {
        t.step().unwrap();
    }
}

#[test]
fn eight_hundred_steps_fit_the_tiny_scene_to_30_db_on_its_views_and_18_db_held_out() {
    let data = tiny_split(48, 32, 0.0);
    let mut t = Trainer::new(tiny_config(), tiny_train_config(1), &data).unwrap();
    train_steps(&mut t, 800);
    let test = tiny_split(4, 32, 0.5);
    let rep = evaluate(t.nerf(), &test, EvalOptions::default()).unwrap();
    let tr = evaluate(t.nerf(), &data, EvalOptions { max_images: Some(4), ..Default::default() }).unwrap();
    eprintln!("tiny scene, training views: PSNR {:.2} dB", tr.psnr);
    eprintln!("tiny scene: PSNR {:.2} dB, SSIM {:.3}, depth {:?} m", rep.psnr, rep.ssim, rep.depth_median_abs_err_m);
    // 48 views of 32×32 pixels fit well but generalise modestly (floaters show on white).
    assert!(tr.psnr >= 30.0, "training-view PSNR {}", tr.psnr);
    assert!(rep.psnr >= 18.0, "held-out PSNR {}", rep.psnr);
    assert!(rep.depth_median_abs_err_m.unwrap() < 0.05);
}

#[test]
fn same_seed_gives_bit_identical_weights_with_one_two_or_three_threads() {
    let data = tiny_split(8, 24, 0.0);
    let run = |threads: usize, seed: u64| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut t = Trainer::new(tiny_config(), tiny_train_config(seed), &data).unwrap();
            train_steps(&mut t, 20);
            t.nerf().params.clone()
        })
    };
    let a = run(1, 7);
    let b = run(2, 7);
    assert!(a == b, "weights differ between 1 and 2 threads");
    // Three threads share the step's eight chunks unevenly, whichever takes which.
    assert!(run(3, 7) == a, "weights differ between 1 and 3 threads");
    let c = run(2, 8);
    assert!(a != c, "a different seed should give different weights");
}

#[test]
fn resume_after_a_kill_ends_at_the_same_weights_as_an_uninterrupted_run() {
    let data = tiny_split(8, 24, 0.0);
    let dir = tempfile::tempdir().unwrap();
    let ck = dir.path().join("ck.safetensors");
    let mut full = Trainer::new(tiny_config(), tiny_train_config(3), &data).unwrap();
    train_steps(&mut full, 40);
    let mut first = Trainer::new(tiny_config(), tiny_train_config(3), &data).unwrap();
    train_steps(&mut first, 23);
    first.save_checkpoint(&ck).unwrap();
    drop(first);
    let mut second = Trainer::resume(&ck, &data).unwrap();
    assert_eq!(second.step_count(), 23);
    train_steps(&mut second, 17);
    assert!(full.nerf().params == second.nerf().params, "resumed weights differ");
    assert_eq!(full.nerf().grid, second.nerf().grid);
}

#[test]
fn checkpoint_round_trip_renders_bit_identically() {
    let data = tiny_split(8, 24, 0.0);
    let mut t = Trainer::new(tiny_config(), tiny_train_config(4), &data).unwrap();
    train_steps(&mut t, 30);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("model.safetensors");
    t.nerf().save(&p).unwrap();
    let loaded = nerfsv_nerf::Nerf::load(&p).unwrap();
    let cam = &data.frames[0].camera;
    let a = t.nerf().render_camera(cam, [1.0, 1.0, 1.0]);
    let b = loaded.render_camera(cam, [1.0, 1.0, 1.0]);
    assert_eq!(a, b);
    // A model-only file cannot be resumed.
    assert!(matches!(Trainer::resume(&p, &data), Err(NerfError::MissingTensor { .. })));
}

#[test]
fn bad_checkpoints_give_typed_errors_naming_the_tensor_or_field() {
    use safetensors::tensor::{Dtype, TensorView};
    let data = tiny_split(4, 16, 0.0);
    let t = Trainer::new(tiny_config(), tiny_train_config(5), &data).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.safetensors");
    t.save_checkpoint(&good).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let (_, md) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let meta = md.metadata().clone().unwrap();
    let rewrite = |name: &str, drop: &str, reshape: Option<&str>, meta: std::collections::HashMap<String, String>| {
        let tensors: Vec<(String, TensorView)> = st
            .tensors()
            .into_iter()
            .filter(|(n, _)| n != drop)
            .map(|(n, v)| {
                if Some(n.as_str()) == reshape {
                    let s = v.shape().iter().rev().copied().collect::<Vec<_>>();
                    (n, TensorView::new(Dtype::F32, s, v.data()).unwrap())
                } else {
                    (n, v)
                }
            })
            .collect();
        let p = dir.path().join(name);
        std::fs::write(&p, safetensors::serialize(tensors, Some(meta)).unwrap()).unwrap();
        p
    };
    let p = rewrite("missing.safetensors", "sigma_net.1.weight", None, meta.clone());
    match nerfsv_nerf::Nerf::load(&p) {
        Err(e @ NerfError::MissingTensor { .. }) => assert!(e.to_string().contains("sigma_net.1.weight")),
        other => panic!("expected MissingTensor, got {other:?}"),
    }
    let p = rewrite("shape.safetensors", "", Some("color_net.0.weight"), meta.clone());
    match nerfsv_nerf::Nerf::load(&p) {
        Err(e @ NerfError::TensorShape { .. }) => assert!(e.to_string().contains("color_net.0.weight")),
        other => panic!("expected TensorShape, got {other:?}"),
    }
    let mut m2 = meta.clone();
    m2.insert("format_version".into(), "99".into());
    let p = rewrite("version.safetensors", "", None, m2);
    match nerfsv_nerf::Nerf::load(&p) {
        Err(e @ NerfError::Version { .. }) => assert!(e.to_string().contains("format_version")),
        other => panic!("expected Version, got {other:?}"),
    }
    // A dataset whose cameras look away from the box.
    let mut far = tiny_split(4, 16, 0.0);
    for f in &mut far.frames {
        f.camera.c2w[(0, 3)] += 50.0;
    }
    assert!(matches!(Trainer::new(tiny_config(), tiny_train_config(5), &far), Err(NerfError::Bounds { .. })));
    // Unwritable output folder.
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    assert!(matches!(t.save_checkpoint(&blocker.join("ck.safetensors")), Err(NerfError::Io { .. })));
}
