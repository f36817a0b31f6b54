//! Images and figures made from a model: the comparison image and the evaluation report.

mod common;

use common::{tiny_config, tiny_split};
use nerfsv_dataset::{Frame, Image};
use nerfsv_nerf::{comparison_image, evaluate, EvalOptions, EvalReport, Nerf, NerfError};

/// The binary's former `write_comparison`, minus the file, as the reference for the pixels.
fn reference(nerf: &Nerf, frames: &[Frame], scale: u32) -> Image {
    let (w, h) = (frames[0].image.width, frames[0].image.height);
    let s = scale.max(1);
    let mut out = Image::new(2 * w * s, h * s * frames.len() as u32);
    for (row, frame) in frames.iter().enumerate() {
        let view = nerf.render_camera(&frame.camera, [1.0, 1.0, 1.0]).to_image();
        for (col, img) in [&frame.image, &view].into_iter().enumerate() {
            for y in 0..h * s {
                for x in 0..w * s {
                    let p = img.pixel(x / s, y / s);
                    let (ox, oy) = (col as u32 * w * s + x, row as u32 * h * s + y);
                    let o = 4 * (oy * out.width + ox) as usize;
                    for c in 0..3 {
                        out.rgba[o + c] = p[c] * p[3] + (1.0 - p[3]);
                    }
                    out.rgba[o + 3] = 1.0;
                }
            }
        }
    }
    out
}

#[test]
fn comparison_image_puts_ground_truth_on_white_left_of_the_render_enlarged_by_scale() {
    let data = tiny_split(2, 12, 0.0);
    let nerf = Nerf::new(tiny_config(), 1).unwrap();
    let img = comparison_image(&nerf, &data.frames, 2).unwrap();
    assert_eq!((img.width, img.height), (2 * 12 * 2, 12 * 2 * 2));
    assert!(img == reference(&nerf, &data.frames, 2), "pixels differ from the binary's former output");
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
    let e = comparison_image(&nerf, &frames, 1).expect_err("sizes differ").to_string();
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
