//! The vision estimator's search: it spends renders only until it has converged.

mod common;

use common::tiny_nerf;

use nalgebra::{Matrix3, Vector3};
use nerfsv_scene::Intrinsics;
use nerfsv_sim::camera::drone_camera;
use nerfsv_sim::estimator::{refine_pose, stratified_pixels, Observation, PosePrior, Starts};
use nerfsv_sim::world::pixel_rays;
use nerfsv_sim::VisionConfig;

/// The tiny model's own image at a pose, read at 64 stratified pixels, and a search config.
struct OwnImage {
    nerf: nerfsv_nerf::Nerf,
    k: Intrinsics,
    p: Vector3<f64>,
    r: Matrix3<f64>,
    cfg: VisionConfig,
    pixels: Vec<[u32; 2]>,
    bg: [f32; 3],
    observed: Vec<[f32; 3]>,
}

fn own_image() -> OwnImage {
    let nerf = tiny_nerf();
    let k = Intrinsics::from_fov_x(32, 32, 0.8);
    let (p, r) = (Vector3::new(0.1, -0.2, 0.3), Matrix3::identity());
    let cfg = VisionConfig { pixels: 64, stop_step: [5e-4, 0.03], ..VisionConfig::default() };
    let pixels = stratified_pixels(&k, cfg.pixels, 4);
    let bg = [1.0; 3];
    let out = nerf.render_rays(&pixel_rays(&drone_camera(k, &p, &r), &pixels, bg));
    let observed = out.rgb.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    OwnImage { nerf, k, p, r, cfg, pixels, bg, observed }
}

/// A prediction that is already the optimum (the image is the model's own render there)
/// proposes a null step at every level: one render, one linearisation, and the prediction back;
/// with every stopping rule off the search spends its whole budget instead, and with only the
/// refused-steps rule, two refused steps per level.
#[test]
fn the_search_stops_at_the_first_step_below_its_tolerance() {
    let OwnImage { nerf, k, p, r, cfg, pixels, bg, observed } = own_image();
    assert!(observed.iter().any(|c| (c[0] - observed[0][0]).abs() > 1e-3), "a flat image tests nothing");

    let prior = PosePrior::isotropic(p, r, 0.05, 3.0);
    let image = Observation { pixels: &pixels, colours: &observed, background: bg };
    let fit = refine_pose(&nerf, k, &prior, image, &cfg, Starts::NONE);
    assert_eq!((fit.renders, fit.linearisations), (1, 1));
    assert_eq!((fit.position, fit.rotation), (p, r));
    assert_eq!(fit.rmse, 0.0);

    let exhaustive = VisionConfig { stop_step: [0.0, 0.0], max_refused: 0, stop_cost_decrease: 0.0, ..cfg.clone() };
    let fit = refine_pose(&nerf, k, &prior, image, &exhaustive, Starts::NONE);
    assert_eq!(fit.renders, cfg.iterations);
    // Null steps do not lower the cost, so no trial is accepted and none is differentiated.
    assert_eq!(fit.linearisations, 1);

    let refusing = VisionConfig { max_refused: 2, ..exhaustive };
    let fit = refine_pose(&nerf, k, &prior, image, &refusing, Starts::NONE);
    let levels = (cfg.levels[0] - cfg.levels[1] + 1) as usize;
    assert_eq!((fit.renders, fit.linearisations), (1 + 2 * levels, 1));
}

/// The start candidates are `2·n` forward renders, scored and never differentiated: from the
/// optimum itself, each candidate 1σ away costs more, so the search starts (and, a null step
/// later, ends) at the prediction, three candidate pairs adding six renders and nothing else.
/// From a start 1σ off along the prior's first principal axis, its candidate pair holds the
/// optimum itself, which the search then starts from.
#[test]
fn start_candidates_are_forward_renders_and_the_cheapest_starts_the_search() {
    let OwnImage { nerf, k, p, r, cfg, pixels, bg, observed } = own_image();
    let image = Observation { pixels: &pixels, colours: &observed, background: bg };

    let at_optimum = PosePrior::isotropic(p, r, 0.05, 3.0);
    let a = refine_pose(&nerf, k, &at_optimum, image, &cfg, Starts::NONE);
    let b = refine_pose(&nerf, k, &at_optimum, image, &cfg, Starts::one_sigma(3));
    assert_eq!((b.renders, b.linearisations), (a.renders + 6, a.linearisations));
    assert_eq!((b.position, b.rotation), (a.position, a.rotation));

    // An anisotropic prior (x the widest, 8 cm) predicting the pose 8 cm off along x: the
    // candidate at −1σ of the first axis is the optimum.
    let mut offset = PosePrior::isotropic(p + Vector3::new(0.08, 0.0, 0.0), r, 0.02, 1.0);
    offset.information[(0, 0)] = 0.08f64.powi(-2);
    let one_pair = VisionConfig { iterations: 1, ..cfg.clone() };
    let fit = refine_pose(&nerf, k, &offset, image, &one_pair, Starts::one_sigma(1));
    assert_eq!(fit.renders, 3);
    assert!((fit.position - p).norm() < 1e-9, "started at {} instead of the optimum {p}", fit.position);
}
