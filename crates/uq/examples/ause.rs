//! Depth AUSE of the GA and BLA uncertainty maps on a trained run's test images.
//!
//! `cargo run --release -p nerfsv-uq --example ause -- RUN [GA_IMAGES] [BLA_IMAGES]`
//! (defaults: `runs/stonehenge`, every test image for GA, 5 for BLA). Per image: the GA fit
//! (σ_d) and its maps, the BLA fit with the default `UqConfig` (its Laplace covariance, the
//! maps linearised at its mode), the rendered z-depth against the ground truth, and the AUSE
//! of the depth error against each map's depth standard deviation (and, for comparison,
//! against its colour standard deviation). Images without ground-truth depth are skipped with
//! a message.

use std::path::PathBuf;
use std::time::Instant;

use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::Nerf;
use nerfsv_uq::{bla_image, bla_maps, depth_errors, ga_image, ga_maps, mean_ause, sparsification, UqConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let run = args.next().map_or_else(|| PathBuf::from("runs/stonehenge"), PathBuf::from);
    let ga_n: Option<usize> = args.next().map(|a| a.parse()).transpose()?;
    let bla_n: usize = args.next().map(|a| a.parse()).transpose()?.unwrap_or(5);
    let nerf = Nerf::load(&run.join("nerf/checkpoint.safetensors"))?;
    let test = load_split(&run.join("dataset"), "test", LoadOptions::default())?;
    let bg = [1.0f32; 3];
    let cfg = UqConfig::default();
    let ga_n = ga_n.unwrap_or(test.frames.len()).min(test.frames.len());
    let (mut ga_depth, mut ga_colour, mut bla_depth, mut bla_colour) = (vec![], vec![], vec![], vec![]);
    let (mut t_ga, mut t_bla_fit, mut t_bla_maps) = (0.0, 0.0, 0.0);
    println!("image,method,sigma_d,ause_depth_std,ause_colour_std,pixels,median_abs_depth_err_m");
    for f in test.frames.iter().take(ga_n.max(bla_n)) {
        let name = f.file_path.as_str();
        let rays = camera_rays(&f.camera, bg);
        let reference: Vec<[f32; 3]> =
            f.image.rgba.chunks_exact(4).map(|p| [0, 1, 2].map(|c| p[c] * p[3] + bg[c] * (1.0 - p[3]))).collect();
        let view = nerf.render_camera(&f.camera, bg);
        let errors = match depth_errors(name, &view.depth, f.depth.as_ref().map(|d| &d.metres[..])) {
            Ok(e) => e,
            Err(e) => {
                eprintln!("skipped: {e}");
                continue;
            }
        };
        let mut valid: Vec<f32> = errors.iter().copied().filter(|v| v.is_finite()).collect();
        valid.sort_by(f32::total_cmp);
        let median = valid.get(valid.len() / 2).copied().unwrap_or(f32::NAN);
        if ga_depth.len() < ga_n {
            let t = Instant::now();
            let ga = ga_image(&nerf, name, &rays, &reference, cfg.ga_sigma_max)?;
            let maps = ga_maps(&nerf, name, &f.camera, bg, ga.sigma_d)?;
            t_ga += t.elapsed().as_secs_f64();
            let d = sparsification(name, &errors, &maps.depth_std)?;
            let c = sparsification(name, &errors, &maps.colour_std)?;
            println!("{name},ga,{:.4},{:.4},{:.4},{},{median:.4}", ga.sigma_d, d.ause, c.ause, d.pixels);
            ga_depth.push(d);
            ga_colour.push(c);
        }
        if bla_depth.len() < bla_n {
            let t = Instant::now();
            let bla = bla_image(&nerf, name, &rays, &reference, &cfg)?;
            t_bla_fit += t.elapsed().as_secs_f64();
            let mut at_mode = nerf.clone();
            for (w, &v) in at_mode.sigma_net_params_mut().iter_mut().zip(&bla.map.theta) {
                *w = v as f32;
            }
            let t = Instant::now();
            let maps = bla_maps(&at_mode, name, &f.camera, bg, &bla.laplace.covariance)?;
            t_bla_maps += t.elapsed().as_secs_f64();
            let d = sparsification(name, &errors, &maps.depth_std)?;
            let c = sparsification(name, &errors, &maps.colour_std)?;
            println!("{name},bla,,{:.4},{:.4},{},{median:.4}", d.ause, c.ause, d.pixels);
            bla_depth.push(d);
            bla_colour.push(c);
        }
    }
    let show = |v: Option<f64>| v.map_or_else(|| "n/a".to_string(), |v| format!("{v:.4}"));
    println!(
        "# GA: {} images, mean depth AUSE {} (colour-std ranking {}), {:.1} ms per image (fit + maps)",
        ga_depth.len(),
        show(mean_ause(&ga_depth)),
        show(mean_ause(&ga_colour)),
        1e3 * t_ga / ga_depth.len().max(1) as f64
    );
    println!(
        "# BLA: {} images, mean depth AUSE {} (colour-std ranking {}), {:.2} s fit + {:.2} s maps per image",
        bla_depth.len(),
        show(mean_ause(&bla_depth)),
        show(mean_ause(&bla_colour)),
        t_bla_fit / bla_depth.len().max(1) as f64,
        t_bla_maps / bla_depth.len().max(1) as f64
    );
    Ok(())
}
