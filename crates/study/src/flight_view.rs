//! The drone's view of its flights: at every recorded substep, the image its camera saw in each
//! world (the world of the rollout's own seed: an ensemble's member, a calibrated world's draw),
//! side by side for flights of the same disturbances, with the estimate's error written under it
//! and marked on it, as an animated PNG.

use nalgebra::{Matrix3, Vector3};
use nerfsv_plot::camera_view::{camera_panels_rgb, CameraPanel};
use nerfsv_scene::Intrinsics;
use nerfsv_sim::camera::drone_camera;
use nerfsv_sim::dynamics::rotation_error;
use nerfsv_sim::{Rollout, Substep, World, WorldKind};

use crate::StudyError;

/// One flight to show: the world it flew in, its record and its seed.
#[derive(Clone, Copy)]
pub struct ViewedFlight<'a> {
    pub world: &'a dyn World,
    pub rollout: &'a Rollout,
    pub seed: u64,
}

/// The camera the drone flies with and the colour it sees where nothing is.
#[derive(Clone, Copy, Debug)]
pub struct DroneCamera {
    pub intrinsics: Intrinsics,
    pub background: [f32; 3],
}

/// How far ahead of the estimated camera the point lies that its `×` marks (m).
pub const AIM_DISTANCE_M: f64 = 1.0;

/// The flights' camera images through time, one panel each, as an APNG played in real time
/// (each flight's recorded substeps; a flight that ended early, by a crash, holds its last
/// frame). Returns the file's bytes and its frame count.
pub fn flight_view_apng(flights: &[ViewedFlight], camera: DroneCamera) -> Result<(Vec<u8>, usize), StudyError> {
    let frames = flights.iter().map(|f| f.rollout.substeps.len()).max().unwrap_or(0);
    if frames == 0 {
        return Err(StudyError::Internal("a flight view needs a flight with at least one substep".into()));
    }
    let k = camera.intrinsics;
    // Panels about 300 px wide, so that their lines of text fit.
    let scale = 300u32.div_ceil(k.width.max(1)).clamp(1, 16);
    let pixels: Vec<[u32; 2]> = (0..k.height).flat_map(|j| (0..k.width).map(move |i| [i, j])).collect();
    let own: Vec<_> = flights.iter().map(|f| f.world.for_rollout(f.seed)).collect();
    let footer = format!("+ where the camera aims, × where the estimate believes it aims ({AIM_DISTANCE_M} m ahead)");
    let mut buffers = Vec::with_capacity(frames);
    let mut size = (0, 0);
    for i in 0..frames {
        let panels: Vec<CameraPanel> = flights
            .iter()
            .zip(&own)
            .map(|(f, own)| {
                let world = own.as_deref().unwrap_or(f.world);
                let held = i >= f.rollout.substeps.len();
                let sub = &f.rollout.substeps[i.min(f.rollout.substeps.len() - 1)];
                panel(world, f.rollout, sub, held, &pixels, camera)
            })
            .collect();
        let (rgb, w, h) =
            camera_panels_rgb(&panels, scale, &footer).map_err(|e| StudyError::Internal(format!("drawing: {e}")))?;
        size = (w, h);
        buffers.push(rgb);
    }
    let longest = flights.iter().map(|f| f.rollout).max_by_key(|r| r.substeps.len()).expect("a flight");
    let span = longest.substeps.last().map_or(0.0, |s| s.time) - longest.substeps[0].time;
    let fps = nerfsv_scene::animation::real_time_fps(frames, span);
    let mut bytes = Vec::new();
    nerfsv_scene::animation::write_apng_rgb(&mut bytes, size.0, size.1, &buffers, fps)
        .map_err(|e| StudyError::Internal(format!("encoding the flight view: {e}")))?;
    Ok((bytes, frames))
}

/// One world's panel at substep `sub` of `rollout` (`held`: the flight ended before this frame).
fn panel(
    world: &dyn World,
    rollout: &Rollout,
    sub: &Substep,
    held: bool,
    pixels: &[[u32; 2]],
    camera: DroneCamera,
) -> CameraPanel {
    let k = camera.intrinsics;
    let (truth, estimate) = (&sub.truth, &sub.estimate);
    let view = drone_camera(k, &truth.position, &truth.rotation);
    let rgb = world
        .observe(&view, pixels, camera.background)
        .iter()
        .flat_map(|c| c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
        .collect();
    let crashed = sub.clearance.is_some_and(|c| c <= 0.0) || (held && rollout.collided());
    let error_mm = 1e3 * (estimate.position - truth.position).norm();
    let error_deg = rotation_error(&estimate.rotation, &truth.rotation).to_degrees();
    let state = match (crashed, sub.clearance) {
        (true, _) => "crashed".to_owned(),
        (false, Some(c)) => format!("clearance {:.0} mm", 1e3 * c),
        (false, None) => "outside the collision grid".to_owned(),
    };
    let world_name = match world.kind() {
        WorldKind::Nerf => "NeRF-sim",
        WorldKind::Gt => "GT-sim",
    };
    CameraPanel {
        title: format!("{world_name}, step {}.{} ({:.1} s)", sub.step, sub.substep, sub.time),
        width: k.width,
        height: k.height,
        rgb,
        lines: vec![format!("estimate off by {error_mm:.0} mm, {error_deg:.2}°"), state],
        estimate_aim: aim(k, truth.position, &truth.rotation, estimate.position, &estimate.rotation),
        crashed,
    }
}

/// Where, in the true camera's image, the point [`AIM_DISTANCE_M`] ahead of the estimated
/// camera lies (`[column, row]`); `None` when it is behind the true camera.
fn aim(
    k: Intrinsics,
    position: Vector3<f64>,
    rotation: &Matrix3<f64>,
    estimated_position: Vector3<f64>,
    estimated_rotation: &Matrix3<f64>,
) -> Option<[f64; 2]> {
    let forward = |p: &Vector3<f64>, r: &Matrix3<f64>| {
        let c = drone_camera(k, p, r);
        (c.c2w.fixed_view::<3, 3>(0, 0).map(f64::from), c.c2w.fixed_view::<3, 1>(0, 3).map(f64::from))
    };
    let (r_est, c_est) = forward(&estimated_position, estimated_rotation);
    // The camera looks down its −z axis.
    let target = c_est + r_est * Vector3::new(0.0, 0.0, -AIM_DISTANCE_M);
    let (r, c) = forward(&position, rotation);
    let q = r.transpose() * (target - c);
    (q.z < -1e-6).then(|| {
        let depth = -q.z;
        [f64::from(k.cx) + f64::from(k.fx) * q.x / depth, f64::from(k.cy) - f64::from(k.fy) * q.y / depth]
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerfsv_sim::dynamics::so3_exp;

    /// The estimate's aim falls at the image centre when it is the truth, off to the side by
    /// `f·tan(θ)` when it is yawed by θ, and nowhere when it looks backwards.
    #[test]
    fn the_estimates_aim_moves_with_its_error() {
        let k = Intrinsics::from_fov_x(100, 80, 1.0);
        let (p, r) = (Vector3::new(0.1, 0.2, 0.3), so3_exp(&Vector3::new(0.0, 0.0, 0.7)));
        let [u, v] = aim(k, p, &r, p, &r).unwrap();
        assert!((u - 50.0).abs() < 1e-4 && (v - 40.0).abs() < 1e-4, "{u} {v}");
        // Yawed left (counter-clockwise from above) by 0.1 rad: the aim moves left in the image.
        let yawed = so3_exp(&Vector3::new(0.0, 0.0, 0.1)) * r;
        let [u, v] = aim(k, p, &r, p, &yawed).unwrap();
        let expected = 50.0 - f64::from(k.fx) * 0.1f64.tan();
        assert!((u - expected).abs() < 1e-3 && (v - 40.0).abs() < 1e-3, "{u} {v}, expected {expected}");
        let backwards = so3_exp(&Vector3::new(0.0, 0.0, std::f64::consts::PI)) * r;
        assert_eq!(aim(k, p, &r, p, &backwards), None);
    }
}
