//! The ensemble as an uncertainty method: the spread of several NeRFs trained on the same data
//! with different seeds (deep ensembles, Lakshminarayanan et al. 2017; for NeRFs, Sünderhauf et
//! al. 2023, "Density-aware NeRF ensembles").
//!
//! Per ray, over the K members' renders (population variances, over the members):
//! - the colour variance, the mean over the three channels of each channel's variance;
//! - the termination variance, the variance of the accumulated opacity (the probability that
//!   the ray ends on a surface), Sünderhauf et al.'s term for what the colour misses where the
//!   members disagree on whether there is anything at all;
//! - the *density-aware* uncertainty, their sum (Sünderhauf et al.'s measure);
//! - the depth standard deviation, of the expected z-depth (0 where a member sees nothing).
//!
//! The depth AUSE ranks the deployed model's (member 0's) depth error by the depth standard
//! deviation, so it scores the same errors as GA's and BLA's AUSE. The per-step measure of a
//! drone's view is the mean density-aware uncertainty over the rays through an even stride of
//! its pixels: it needs no ground-truth image.

use nerfsv_nerf::{Nerf, RayInput, RayOutputs};
use nerfsv_scene::Camera;

use crate::ause::{depth_errors, sparsification, Sparsification};
use crate::maps::UncertaintyMaps;
use crate::UqError;

/// Per-ray spread of an ensemble's renders.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EnsembleSpread {
    /// Mean over the channels of each channel's variance across members.
    pub colour_var: Vec<f32>,
    /// Variance of the accumulated opacity across members.
    pub termination_var: Vec<f32>,
    /// Standard deviation of the ray's expected distance (metres; z-depth for a camera's maps).
    pub depth_std: Vec<f32>,
}

impl EnsembleSpread {
    /// The density-aware uncertainty per ray: colour variance plus termination variance.
    pub fn density_aware(&self) -> Vec<f32> {
        self.colour_var.iter().zip(&self.termination_var).map(|(c, t)| c + t).collect()
    }

    /// The spread of `outputs`, one member's renders of the same rays each, with `depths` the
    /// per-ray depth each member assigns (its `distance`, or z-depth).
    pub fn of(outputs: &[RayOutputs], depths: &[&[f32]]) -> Self {
        let rays = outputs.first().map_or(0, |o| o.opacity.len());
        let mut s = Self {
            colour_var: Vec::with_capacity(rays),
            termination_var: Vec::with_capacity(rays),
            depth_std: Vec::with_capacity(rays),
        };
        let variance = |values: &mut dyn Iterator<Item = f64>| {
            let (mut n, mut sum, mut sq) = (0.0, 0.0, 0.0);
            for v in values {
                n += 1.0;
                sum += v;
                sq += v * v;
            }
            let mean = sum / n;
            (sq / n - mean * mean).max(0.0)
        };
        for r in 0..rays {
            let colour =
                (0..3).map(|c| variance(&mut outputs.iter().map(|o| f64::from(o.rgb[3 * r + c])))).sum::<f64>() / 3.0;
            s.colour_var.push(colour as f32);
            s.termination_var.push(variance(&mut outputs.iter().map(|o| f64::from(o.opacity[r]))) as f32);
            s.depth_std.push(variance(&mut depths.iter().map(|d| f64::from(d[r]))).sqrt() as f32);
        }
        s
    }
}

/// Every member's render of `rays` and their spread (distance as depth).
pub fn ray_spread(members: &[&Nerf], rays: &[RayInput]) -> (Vec<RayOutputs>, EnsembleSpread) {
    let outputs: Vec<RayOutputs> = members.iter().map(|m| m.render_rays(rays)).collect();
    let depths: Vec<&[f32]> = outputs.iter().map(|o| &o.distance[..]).collect();
    let spread = EnsembleSpread::of(&outputs, &depths);
    (outputs, spread)
}

/// The per-pixel maps of `camera` (row-major): every member's rendered view, and the spread
/// with z-depth as the depth.
pub fn camera_spread(
    members: &[&Nerf],
    camera: &Camera,
    background: [f32; 3],
) -> (Vec<nerfsv_nerf::RenderedView>, EnsembleSpread) {
    let views: Vec<nerfsv_nerf::RenderedView> = members.iter().map(|m| m.render_camera(camera, background)).collect();
    let outputs: Vec<RayOutputs> = views
        .iter()
        .map(|v| RayOutputs {
            rgb: v.rgb.clone(),
            opacity: v.opacity.clone(),
            distance: v.distance.clone(),
            samples: v.samples,
        })
        .collect();
    let depths: Vec<&[f32]> = views.iter().map(|v| &v.depth[..]).collect();
    let spread = EnsembleSpread::of(&outputs, &depths);
    (views, spread)
}

/// The per-pixel maps of `camera` (row-major): the members' colour standard deviation (the
/// square root of the mean channel variance) and z-depth standard deviation; 0 where they agree,
/// also where no member sees anything.
pub fn maps(members: &[&Nerf], camera: &Camera, background: [f32; 3]) -> UncertaintyMaps {
    let (_, spread) = camera_spread(members, camera, background);
    let k = camera.intrinsics;
    UncertaintyMaps {
        width: k.width,
        height: k.height,
        colour_std: spread.colour_var.iter().map(|v| v.sqrt()).collect(),
        depth_std: spread.depth_std,
    }
}

/// The per-step measure of a drone's view: the mean density-aware uncertainty over the rays
/// through `pixels` (column, row) of `camera`.
pub fn view_uncertainty(members: &[&Nerf], camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> f64 {
    let rays: Vec<RayInput> = pixels.iter().map(|&[i, j]| RayInput::through_pixel(camera, i, j, background)).collect();
    let (_, spread) = ray_spread(members, &rays);
    let values = spread.density_aware();
    values.iter().map(|&v| f64::from(v)).sum::<f64>() / values.len().max(1) as f64
}

/// The depth AUSE of one test image: the deployed model's (`members[0]`'s) depth error against
/// `ground_truth`, ranked by the ensemble's depth standard deviation; and, as the baseline, the
/// same errors in a random order (seeded by `seed`).
pub fn depth_ause(
    members: &[&Nerf],
    image: &str,
    camera: &Camera,
    ground_truth: Option<&[f32]>,
    background: [f32; 3],
    seed: u64,
) -> Result<(Sparsification, Sparsification), UqError> {
    let (views, spread) = camera_spread(members, camera, background);
    let errors = depth_errors(image, &views[0].depth, ground_truth)?;
    let random: Vec<f32> = (0..errors.len()).map(|p| unit_hash(seed, p as u64)).collect();
    Ok((sparsification(image, &errors, &spread.depth_std)?, sparsification(image, &errors, &random)?))
}

/// A uniform number in [0, 1) from a seed and an index (SplitMix64).
fn unit_hash(seed: u64, i: u64) -> f32 {
    let mut z = seed.wrapping_add(i.wrapping_mul(0x9E37_79B9_7F4A_7C15)).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 40) as f32 / (1u64 << 24) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn outputs(rgb: [f32; 3], opacity: f32, distance: f32) -> RayOutputs {
        RayOutputs { rgb: rgb.to_vec(), opacity: vec![opacity], distance: vec![distance], samples: 0 }
    }

    #[test]
    fn identical_members_have_no_spread_and_two_members_the_closed_form_variance() {
        let same = [outputs([0.2, 0.4, 0.6], 0.9, 3.0), outputs([0.2, 0.4, 0.6], 0.9, 3.0)];
        let d: Vec<&[f32]> = same.iter().map(|o| &o.distance[..]).collect();
        let s = EnsembleSpread::of(&same, &d);
        assert_eq!((s.colour_var[0], s.termination_var[0], s.depth_std[0]), (0.0, 0.0, 0.0));
        // Two members a apart: population variance (a/2)².
        let two = [outputs([0.0, 0.0, 0.0], 1.0, 2.0), outputs([0.2, 0.4, 0.6], 0.0, 4.0)];
        let d: Vec<&[f32]> = two.iter().map(|o| &o.distance[..]).collect();
        let s = EnsembleSpread::of(&two, &d);
        let colour = (0.1f64.powi(2) + 0.2f64.powi(2) + 0.3f64.powi(2)) / 3.0;
        assert!((f64::from(s.colour_var[0]) - colour).abs() < 1e-7, "{s:?}");
        assert!((s.termination_var[0] - 0.25).abs() < 1e-7);
        assert!((s.depth_std[0] - 1.0).abs() < 1e-6);
        assert!((f64::from(s.density_aware()[0]) - (colour + 0.25)).abs() < 1e-6);
    }

    #[test]
    fn the_random_order_is_seeded_and_uniform() {
        let a: Vec<f32> = (0..10_000).map(|i| unit_hash(3, i)).collect();
        assert_eq!(a, (0..10_000).map(|i| unit_hash(3, i)).collect::<Vec<_>>());
        assert!(a.iter().all(|&x| (0.0..1.0).contains(&x)));
        let mean = a.iter().map(|&x| f64::from(x)).sum::<f64>() / a.len() as f64;
        assert!((mean - 0.5).abs() < 0.01, "{mean}");
    }
}
