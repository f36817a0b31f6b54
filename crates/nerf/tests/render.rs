//! Images and figures made from a model: the comparison image and the evaluation report.

mod common;

use common::{tiny_config, tiny_split};
use nerfsv_nerf::{comparison_image, evaluate, EvalOptions, EvalReport, Nerf, NerfError};

#[test]
fn comparison_image_puts_ground_truth_on_white_left_of_the_render_enlarged_by_scale() {
    let data = tiny_split(2, 12, 0.0);
    let nerf = Nerf::new(tiny_config(), 1).unwrap();
    let views: Vec<_> = data.frames.iter().map(|f| f.view()).collect();
    let img = comparison_image(&nerf, &views, 2).unwrap();
    assert_eq!((img.width, img.height), (2 * 12 * 2, 12 * 2 * 2));
    // Right half of row 0 = the NeRF's render of frame 0, each pixel 2×2.
    let view = nerf.render_camera(&data.frames[0].camera, [1.0; 3]).to_image();
    for y in 0..24 {
        for x in 0..24 {
            let p = view.pixel(x / 2, y / 2);
            let on_white = |c: usize| p[c] * p[3] + (1.0 - p[3]);
            assert_eq!(img.pixel(24 + x, y), [on_white(0), on_white(1), on_white(2), 1.0], "render ({x}, {y})");
        }
    }
    // Left half of row 1 = frame 1's ground truth on white, each pixel 2×2.
    let gt = &data.frames[1].image;
    let mut transparent = 0;
    for y in 0..24 {
        for x in 0..24 {
            let p = gt.pixel(x / 2, y / 2);
            let on_white = |c: usize| p[c] * p[3] + (1.0 - p[3]);
            let want = [on_white(0), on_white(1), on_white(2), 1.0];
            assert_eq!(img.pixel(x, 24 + y), want, "({x}, {y})");
            transparent += (p[3] == 0.0) as usize;
        }
    }
    assert!(transparent > 0, "the test scene must show background, to check the compositing");
    assert_eq!(img.pixel(0, 24), [1.0; 4], "a transparent corner is white");
}

#[test]
fn comparison_image_refuses_no_frames_and_frames_of_different_sizes() {
    let nerf = Nerf::new(tiny_config(), 1).unwrap();
    match comparison_image(&nerf, &[], 2) {
        Err(NerfError::Invalid(e)) => assert_eq!(e.field, "frames"),
        other => panic!("expected Invalid, got {:?}", other.map(|i| i.width)),
    }
    let mut frames = tiny_split(2, 12, 0.0).frames;
    frames[1] = tiny_split(1, 10, 0.0).frames.remove(0);
    let views: Vec<_> = frames.iter().map(|f| f.view()).collect();
    let e = comparison_image(&nerf, &views, 1).expect_err("sizes differ").to_string();
    assert!(e.contains("frames[1]") && e.contains("12×12") && e.contains("10×10"), "{e}");
}

#[test]
fn evaluate_refuses_zero_images_instead_of_reporting_nan() {
    let nerf = Nerf::new(tiny_config(), 1).unwrap();
    let data = tiny_split(2, 12, 0.0);
    match evaluate(&nerf, &data, EvalOptions { max_images: Some(0), ..EvalOptions::default() }) {
        Err(NerfError::Invalid(e)) => assert_eq!(e.to_string(), "max_images: must be at least 1, found 0"),
        other => panic!("expected Invalid, got {other:?}"),
    }
    let empty = nerfsv_dataset::Split { frames: Vec::new(), ..data };
    match evaluate(&nerf, &empty, EvalOptions::default()) {
        Err(e @ NerfError::EmptySplit { .. }) => assert!(e.to_string().contains("transforms_train.json"), "{e}"),
        other => panic!("expected EmptySplit, got {other:?}"),
    }
}

#[test]
fn evaluate_refuses_images_smaller_than_the_ssim_window_instead_of_reporting_nan() {
    let nerf = Nerf::new(tiny_config(), 1).unwrap();
    let e = evaluate(&nerf, &tiny_split(2, 10, 0.0), EvalOptions::default()).unwrap_err().to_string();
    assert!(e.contains("frame 0") && e.contains("11×11") && e.contains("found 10×10"), "{e}");
}

#[test]
fn eval_report_reads_back_as_the_same_typed_figures() {
    let nerf = Nerf::new(tiny_config(), 1).unwrap();
    let report = evaluate(&nerf, &tiny_split(2, 12, 0.0), EvalOptions::default()).unwrap();
    assert!(report.psnr.is_finite() && report.ssim.is_finite(), "{report:?}");
    let text = serde_json::to_string(&report).unwrap();
    let back: EvalReport = serde_json::from_str(&text).unwrap();
    assert_eq!(back, report);
}

/// `ray_composites_a_sample` (marching only) agrees with the render on every ray: rays that
/// miss the box, rays through a grid with only a few occupied cells (so many meet none of them),
/// rays starting inside the box, and rays whose jitter decides whether the lattice touches a
/// one-cell-thick occupied slab.
#[test]
fn a_ray_composites_a_sample_exactly_when_the_render_gives_it_one() {
    use nerfsv_nerf::RayInput;
    use rand::{RngExt, SeedableRng};
    let mut nerf = Nerf::new(tiny_config(), 3).unwrap();
    let res = nerf.grid.resolution;
    nerf.grid.fill_occupied(false);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    for _ in 0..res * res {
        let c = [rng.random_range(0..res), rng.random_range(0..res), rng.random_range(0..res)];
        let i = nerf.grid.index(c);
        nerf.grid.set_occupied(i, true);
    }
    let rays: Vec<RayInput> = (0..4000)
        .map(|_| {
            let origin = [0, 1, 2].map(|_| rng.random_range(-2.5f32..2.5));
            let d = [0, 1, 2].map(|_| rng.random_range(-1.0f32..1.0));
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-3);
            RayInput {
                origin: origin.into(),
                direction: d.map(|x| x / n).into(),
                background: [1.0; 3],
                jitter: rng.random(),
            }
        })
        .collect();
    let out = nerf.render_rays_samples(&rays);
    let (mut hits, mut misses) = (0, 0);
    for (i, r) in rays.iter().enumerate() {
        let rendered = !out.ray(i).1.is_empty();
        assert_eq!(nerf.ray_composites_a_sample(r), rendered, "ray {i}: {r:?}");
        if rendered {
            hits += 1;
        } else {
            misses += 1;
        }
    }
    assert!(hits > 400 && misses > 400, "both kinds must occur: {hits} hits, {misses} misses");
    let listed: Vec<usize> = (0..rays.len()).filter(|&i| !out.ray(i).1.is_empty()).collect();
    assert_eq!(nerf.rays_compositing_a_sample(&rays), listed);
    // The samples handed to `map_ray_samples` are those `render_rays_samples` keeps, in ray order.
    let mapped = nerf.map_ray_samples(&rays, |i, c, w| (i, c.to_vec(), w.to_vec()));
    assert_eq!(mapped.len(), rays.len());
    for (i, (j, c, w)) in mapped.into_iter().enumerate() {
        assert_eq!((j, c.as_slice(), w.as_slice()), (i, out.ray(i).0, out.ray(i).1), "ray {i}");
    }
}
