//! The reference trajectory along a planned path: where the drone should be, how fast, and
//! where its camera should look, at every time.
//!
//! **Timing.** Arc length follows the minimum-jerk time scaling `s(t) = L·(10u³ − 15u⁴ + 6u⁵)`,
//! `u = t/T` clamped to [0, 1] (L the polyline's length), so the drone starts and ends at rest.
//!
//! **Shape.** A polyline's corners would ask for an instant change of velocity, which no drone
//! can follow: it would swing wide of every corner. Each corner is therefore rounded by
//! convolving the polyline's direction with a triangular kernel of half-width `w` (in arc
//! length) centred on the corner: the curve `c(s)` keeps the start, the
//! goal and every straight stretch farther than `w` from a corner, has continuous curvature, and
//! passes inside the corner by `|Δt|·w/6` (Δt the change of unit direction there). `w` is the
//! largest value up to [`MAX_BLEND`] that keeps that cut within [`CORNER_CUT`] and the blends
//! apart (half of each neighbouring segment; all of the first and last). Position is `c(s)`,
//! velocity `c′·ṡ`, acceleration `c″·ṡ² + c′·s̈`, jerk `c‴·ṡ³ + 3c″·ṡ·s̈ + c′·s⃛`: the exact time
//! derivatives of the position, corner curvature included.
//!
//! **Heading.** Body +x (where the camera looks) is the horizontal direction of a 0.2 m
//! look-ahead chord of the polyline, so yaw turns smoothly ahead of corners.
//!
//! ```
//! use nalgebra::Vector3;
//! use nerfsv_sim::planner::PlannedPath;
//! use nerfsv_sim::reference::ReferenceTrajectory;
//!
//! let path = PlannedPath { points: vec![Vector3::new(0.0, 0.0, 0.3), Vector3::new(1.0, 0.0, 0.3)] };
//! let traj = ReferenceTrajectory::new(&path, 4.0);
//! let mid = traj.at(2.0);
//! assert!((mid.position.x - 0.5).abs() < 1e-12);
//! assert!((mid.velocity.x - 1.875 / 4.0).abs() < 1e-12); // peak speed 15L/(8T)
//! assert_eq!(traj.at(9.0).velocity, Vector3::zeros());
//! ```

use nalgebra::Vector3;

use crate::dynamics::State;
use crate::planner::PlannedPath;

/// Length of the look-ahead chord that sets the heading, metres.
const HEADING_LOOKAHEAD: f64 = 0.2;
/// Largest distance the rounded reference passes inside a corner of the path, metres. Equal to
/// the planner's default margin, so the reference keeps at least the body's half-diagonal from
/// geometry wherever the planned polyline keeps the required clearance.
pub const CORNER_CUT: f64 = 0.03;
/// Largest half-width of a corner's blend, metres of arc length.
pub const MAX_BLEND: f64 = 0.3;

/// The reference at one instant (metres, seconds, world frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reference {
    pub position: Vector3<f64>,
    pub velocity: Vector3<f64>,
    pub acceleration: Vector3<f64>,
    /// Time derivative of the acceleration, m/s³ (the controller turns it into the desired body
    /// rate).
    pub jerk: Vector3<f64>,
    /// Desired direction of body +x (the camera's view): a horizontal unit vector.
    pub heading: Vector3<f64>,
}

impl Reference {
    /// Hold `position` at rest, facing `heading` (made horizontal and unit; +x if it has no
    /// horizontal part).
    pub fn hover(position: Vector3<f64>, heading: Vector3<f64>) -> Self {
        Self {
            position,
            velocity: Vector3::zeros(),
            acceleration: Vector3::zeros(),
            jerk: Vector3::zeros(),
            heading: horizontal_unit(&heading).unwrap_or_else(Vector3::x),
        }
    }
}

/// One rounded corner: at arc length `s` the unit direction changes by `delta`, spread over
/// `[s − w, s + w]`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Corner {
    s: f64,
    delta: Vector3<f64>,
    w: f64,
}

/// A planned path timed by the minimum-jerk profile, corners rounded; see the module docs.
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceTrajectory {
    path: PlannedPath,
    length: f64,
    duration: f64,
    /// Direction of the first segment with length (zero for a path without length).
    first_tangent: Vector3<f64>,
    corners: Vec<Corner>,
    /// Heading where no look-ahead chord has a horizontal part (a vertical path): +x.
    fallback_heading: Vector3<f64>,
}

impl ReferenceTrajectory {
    /// The path traversed in `duration` seconds. A duration that is not positive and finite
    /// gives the goal at rest at every time.
    pub fn new(path: &PlannedPath, duration: f64) -> Self {
        let duration = if duration.is_finite() && duration > 0.0 { duration } else { 0.0 };
        // Segments with length: (start arc length, length, unit direction).
        let mut segments = Vec::new();
        let mut acc = 0.0;
        for w in path.points.windows(2) {
            let len = (w[1] - w[0]).norm();
            if len > 0.0 {
                segments.push((acc, len, (w[1] - w[0]) / len));
                acc += len;
            }
        }
        let last = segments.len().saturating_sub(1);
        let corners = segments
            .windows(2)
            .enumerate()
            .filter_map(|(i, pair)| {
                let ((_, len0, t0), (s, len1, t1)) = (pair[0], pair[1]);
                let delta = t1 - t0;
                let turn = delta.norm();
                if turn < 1e-12 {
                    return None;
                }
                // The first and last segment have no other blend to share with.
                let room0 = if i == 0 { len0 } else { 0.5 * len0 };
                let room1 = if i + 1 == last { len1 } else { 0.5 * len1 };
                let w = MAX_BLEND.min(6.0 * CORNER_CUT / turn).min(room0).min(room1);
                Some(Corner { s, delta, w })
            })
            .collect();
        let first_tangent = segments.first().map_or_else(Vector3::zeros, |s| s.2);
        let mut traj =
            Self { path: path.clone(), length: acc, duration, first_tangent, corners, fallback_heading: Vector3::x() };
        // The first chord with a horizontal part, scanning from the start.
        let n = (traj.length / (0.25 * HEADING_LOOKAHEAD)).ceil() as usize;
        traj.fallback_heading =
            (0..=n).find_map(|i| traj.chord_heading(i as f64 * 0.25 * HEADING_LOOKAHEAD)).unwrap_or_else(Vector3::x);
        traj
    }

    /// Duration of the motion, seconds; after it the reference holds the goal.
    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// The path being followed.
    pub fn path(&self) -> &PlannedPath {
        &self.path
    }

    /// Yaw of the heading at time 0 (radians from world +x): the yaw to start the drone with.
    pub fn initial_yaw(&self) -> f64 {
        let h = self.at(0.0).heading;
        h.y.atan2(h.x)
    }

    /// The drone at rest where the reference is at time `t`, facing its heading: the start
    /// state at `t = 0`, and the nominal pose at the end of a step.
    pub fn at_rest(&self, t: f64) -> State {
        let r = self.at(t);
        State::at_rest(r.position, r.heading.y.atan2(r.heading.x))
    }

    /// The reference at time `t` seconds (clamped to `[0, duration]`).
    pub fn at(&self, t: f64) -> Reference {
        let [s, s1, s2, s3] = self.arc_length(t);
        let [c, c1, c2, c3] = self.curve(s);
        Reference {
            position: c,
            velocity: c1 * s1,
            acceleration: c2 * (s1 * s1) + c1 * s2,
            jerk: c3 * (s1 * s1 * s1) + c2 * (3.0 * s1 * s2) + c1 * s3,
            heading: self.chord_heading(s).unwrap_or(self.fallback_heading),
        }
    }

    /// Arc length and its first three time derivatives at `t` (minimum-jerk profile).
    fn arc_length(&self, t: f64) -> [f64; 4] {
        if self.duration == 0.0 {
            return [self.length, 0.0, 0.0, 0.0];
        }
        // At rest outside the motion (the profile's jerk jumps at both ends).
        if t.is_nan() || t <= 0.0 {
            return [0.0; 4];
        }
        if t >= self.duration {
            return [self.length, 0.0, 0.0, 0.0];
        }
        let u = t / self.duration;
        let (l, tt) = (self.length, self.duration);
        let u2 = u * u;
        [
            l * u2 * u * (10.0 - 15.0 * u + 6.0 * u2),
            l / tt * 30.0 * u2 * (1.0 - u) * (1.0 - u),
            l / (tt * tt) * 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u),
            l / (tt * tt * tt) * 60.0 * (1.0 - 6.0 * u + 6.0 * u2),
        ]
    }

    /// The rounded curve and its first three derivatives with respect to arc length at `s`.
    ///
    /// With the triangular kernel of half-width `w`, a unit change `Δ` of direction at `s_c`
    /// adds `Δ·R(x)`, `x = s − s_c`, to the polyline, where (zero for |x| ≥ w)
    /// `R = (w − |x|)³/(6w²)`; the direction becomes `t₀ + Σ Δ·C(x)` with the kernel's CDF `C`,
    /// the second derivative `Σ Δ·Λ(x)` with `Λ = (w − |x|)/w²`, the third `Σ Δ·Λ′(x)`.
    fn curve(&self, s: f64) -> [Vector3<f64>; 4] {
        let mut c = self.path.point_at(s);
        let mut c1 = self.first_tangent;
        let mut c2 = Vector3::zeros();
        let mut c3 = Vector3::zeros();
        let s = s.clamp(0.0, self.length);
        for k in &self.corners {
            let (x, w) = (s - k.s, k.w);
            if x >= w {
                c1 += k.delta;
                continue;
            }
            if x <= -w {
                continue;
            }
            let r = w - x.abs();
            let w2 = w * w;
            c += k.delta * (r * r * r / (6.0 * w2));
            let cdf = if x <= 0.0 { r * r / (2.0 * w2) } else { 1.0 - r * r / (2.0 * w2) };
            c1 += k.delta * cdf;
            c2 += k.delta * (r / w2);
            c3 += k.delta * (-x.signum() / w2);
        }
        // The polyline's own kink at a corner is what R's kink cancels: c is C¹ (C² with c2).
        [c, c1, c2, c3]
    }

    /// Horizontal direction of the look-ahead chord at `s`; the chord is moved back from the goal
    /// so that it keeps its full length there. `None` where it has no horizontal part.
    fn chord_heading(&self, s: f64) -> Option<Vector3<f64>> {
        let a = HEADING_LOOKAHEAD.min(self.length);
        let s0 = s.min(self.length - a).max(0.0);
        horizontal_unit(&(self.path.point_at(s0 + a) - self.path.point_at(s0)))
    }
}

/// `v` without its z component, normalised; `None` if nearly vertical or zero.
fn horizontal_unit(v: &Vector3<f64>) -> Option<Vector3<f64>> {
    let h = Vector3::new(v.x, v.y, 0.0);
    let n = h.norm();
    (n > 1e-9).then(|| h / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn zigzag() -> PlannedPath {
        PlannedPath {
            points: vec![
                Vector3::new(0.39, -0.67, 0.2),
                Vector3::new(-0.2, -0.1, 0.2),
                Vector3::new(-0.25, 0.2, 0.3),
                Vector3::new(-0.4, 0.55, 0.16),
            ],
        }
    }

    #[test]
    fn velocity_acceleration_and_jerk_are_the_time_derivatives_of_the_reference() {
        let traj = ReferenceTrajectory::new(&zigzag(), 4.8);
        let h = 1e-5;
        for k in 1..480 {
            let t = k as f64 * 0.01 + 0.003;
            let (a, r, b) = (traj.at(t - h), traj.at(t), traj.at(t + h));
            let d = |x: Vector3<f64>, y: Vector3<f64>| (y - x) / (2.0 * h);
            assert!((d(a.position, b.position) - r.velocity).norm() < 1e-8, "velocity at {t}");
            assert!((d(a.velocity, b.velocity) - r.acceleration).norm() < 1e-7, "acceleration at {t}");
            // The jerk jumps where a blend begins or ends; skip the samples straddling one.
            let jd = d(a.acceleration, b.acceleration) - r.jerk;
            assert!(jd.norm() < 1e-5 || (traj.at(t - h).jerk - traj.at(t + h).jerk).norm() > 1e-3, "jerk at {t}");
        }
    }

    #[test]
    fn motion_starts_and_ends_at_rest_on_the_path_ends() {
        let path = zigzag();
        let traj = ReferenceTrajectory::new(&path, 4.8);
        for (t, at) in [(-1.0, path.points[0]), (0.0, path.points[0]), (4.8, path.points[3]), (9.0, path.points[3])] {
            let r = traj.at(t);
            assert!((r.position - at).norm() < 1e-12, "{t}: {:?}", r.position);
            assert_eq!((r.velocity, r.acceleration, r.jerk), (Vector3::zeros(), Vector3::zeros(), Vector3::zeros()));
        }
    }

    #[test]
    fn a_straight_path_follows_the_minimum_jerk_profile() {
        let path = PlannedPath { points: vec![Vector3::new(0.0, 0.0, 0.3), Vector3::new(0.0, 1.5, 0.3)] };
        let traj = ReferenceTrajectory::new(&path, 3.0);
        for k in 0..=30 {
            let t = k as f64 * 0.1;
            let u: f64 = t / 3.0;
            let s = 1.5 * (10.0 * u.powi(3) - 15.0 * u.powi(4) + 6.0 * u.powi(5));
            let r = traj.at(t);
            assert!((r.position.y - s).abs() < 1e-12 && r.position.x == 0.0);
            assert_eq!(r.heading, Vector3::y());
        }
        assert!((traj.at(1.5).velocity.y - 15.0 * 1.5 / (8.0 * 3.0)).abs() < 1e-12);
    }

    #[test]
    fn corners_are_rounded_inside_by_at_most_the_corner_cut_and_straights_are_kept() {
        let path = zigzag();
        let traj = ReferenceTrajectory::new(&path, 4.8);
        let mut worst = 0f64;
        for k in 0..=4800 {
            let r = traj.at(k as f64 * 1e-3);
            // Distance to the polyline.
            let d = path
                .points
                .windows(2)
                .map(|w| {
                    let e = w[1] - w[0];
                    let t = ((r.position - w[0]).dot(&e) / e.norm_squared()).clamp(0.0, 1.0);
                    (w[0] + e * t - r.position).norm()
                })
                .fold(f64::INFINITY, f64::min);
            worst = worst.max(d);
        }
        assert!(worst <= CORNER_CUT + 1e-9 && worst > 0.5 * CORNER_CUT, "largest cut {worst}");
        // The middle of the first segment lies farther than MAX_BLEND from any corner: unchanged.
        let s = 0.5 * (path.points[1] - path.points[0]).norm();
        assert!(s > MAX_BLEND);
        assert_eq!(traj.curve(s)[0], path.point_at(s));
        assert_eq!(traj.curve(s)[1], path.tangent_at(s));
    }

    #[test]
    fn heading_is_a_horizontal_unit_vector_that_turns_smoothly_and_holds_at_the_goal() {
        let traj = ReferenceTrajectory::new(&zigzag(), 4.8);
        let mut prev = traj.at(0.0).heading;
        for k in 1..=600 {
            let h = traj.at(k as f64 * 0.01).heading;
            assert!(h.z == 0.0 && (h.norm() - 1.0).abs() < 1e-12);
            // At most 0.35 rad per 10 ms at the 0.6 m/s peak speed (a 0.2 m chord).
            assert!(h.angle(&prev) < 0.05, "heading jumps at {}", k as f64 * 0.01);
            prev = h;
        }
        let last = zigzag().points[3] - zigzag().points[2];
        let expected = Vector3::new(last.x, last.y, 0.0).normalize();
        assert!((traj.at(4.8).heading - expected).norm() < 1e-12);
        assert!((traj.initial_yaw() - 0.57f64.atan2(-0.59)).abs() < 1e-9);
        // A vertical path has no horizontal direction: +x.
        let up = PlannedPath { points: vec![Vector3::new(0.0, 0.0, 0.2), Vector3::new(0.0, 0.0, 0.4)] };
        assert_eq!(ReferenceTrajectory::new(&up, 2.0).at(1.0).heading, Vector3::x());
    }

    #[test]
    fn degenerate_paths_and_durations_hold_the_goal() {
        let single = PlannedPath { points: vec![Vector3::new(0.1, 0.2, 0.3)] };
        let r = ReferenceTrajectory::new(&single, 4.0).at(1.0);
        assert_eq!(r.position, Vector3::new(0.1, 0.2, 0.3));
        assert_eq!(r.velocity, Vector3::zeros());
        let z = ReferenceTrajectory::new(&zigzag(), 0.0);
        assert_eq!(z.at(0.0).position, zigzag().points[3]);
        assert_eq!(ReferenceTrajectory::new(&zigzag(), f64::NAN).duration(), 0.0);
    }
}
