//! The path planner: A* over the nodes of a signed distance field, then shortcut smoothing, as
//! NeRF-Navigation plans on the NeRF's occupancy.
//!
//! The drone is treated as a ball of radius [`required_clearance`]: its body's half-diagonal (so
//! any orientation fits) plus a margin for tracking error. A point is *usable* when it lies in the
//! altitude band and the field there is at least that radius; a straight segment is *clear* when
//! the trilinear field sampled every ≤ ⅛ cell along it is usable.
//!
//! 1. The start and goal are checked: inside the grid (with the body), inside the altitude band,
//!    and usable; each failure is its own [`PlanError`] naming the point and the numbers.
//! 2. If the straight segment start → goal is clear, that is the path (2 points).
//! 3. Otherwise A* runs over the usable grid nodes of the band (26-neighbour moves, Euclidean
//!    cost and heuristic, ties broken by node index so the result is deterministic). A move is
//!    allowed only when every node of the cell, face or edge it crosses is usable: the trilinear
//!    field is a convex combination of those nodes, so the whole move is usable, not just its
//!    ends. Start and goal join their nearest usable node by a clear segment.
//! 4. Greedy shortcutting: from each kept point, jump to the farthest later point with a clear
//!    segment.
//!
//! ```
//! use nalgebra::Vector3;
//! use nerfsv_collision::{drone_half_extents, ScalarGrid, SdfGrid};
//! use nerfsv_scene::Aabb;
//! use nerfsv_sim::planner::{plan, PlannerConfig};
//!
//! // An empty room: nothing blocks, so the path is the straight segment.
//! let bounds = Aabb::new([-1.0, -1.0, 0.0].into(), [1.0, 1.0, 0.7].into());
//! let field = SdfGrid::from_field(&ScalarGrid::sample(&bounds, 40.0, |p| p.z + 1.0), 0.0, true);
//! let (start, goal) = (Vector3::new(-0.5, 0.0, 0.3), Vector3::new(0.5, 0.2, 0.3));
//! let path = plan(&field, start, goal, drone_half_extents(), &PlannerConfig::default()).unwrap();
//! assert_eq!(path.points, vec![start, goal]);
//! ```

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::fmt;

use nalgebra::{Point3, Vector3};
use nerfsv_collision::SdfGrid;
use nerfsv_scene::validate::{finite, non_negative, InvalidValue};
use serde::{Deserialize, Serialize};

/// Planner settings.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlannerConfig {
    /// Clearance kept beyond the body's half-diagonal, metres: room for tracking error.
    /// Default 0.03.
    pub margin: f64,
    /// Altitudes the path may use, metres `[min, max]` (of the body centre). Default `[0.15, 0.5]`.
    pub altitude: [f64; 2],
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self { margin: 0.03, altitude: [0.15, 0.5] }
    }
}

impl PlannerConfig {
    /// The margin finite and ≥ 0, the band finite with `min ≤ max`; the error names the field
    /// (`planner.margin`, `planner.altitude[1]`) and the value found.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        non_negative("margin", self.margin)?;
        finite("altitude[0]", self.altitude[0])?;
        finite("altitude[1]", self.altitude[1])?;
        if self.altitude[1] < self.altitude[0] {
            return Err(InvalidValue::new(
                "altitude[1]",
                format!("must be at least planner.altitude[0] = {}", self.altitude[0]),
                self.altitude[1],
            ));
        }
        Ok(())
    }
}

/// A planned path: a polyline from start to goal (metres, world frame).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlannedPath {
    /// Vertices, start first and goal last.
    pub points: Vec<Vector3<f64>>,
}

impl PlannedPath {
    /// Total length, metres.
    pub fn length(&self) -> f64 {
        self.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
    }

    /// The point at arc length `s` from the start, `s` clamped to `[0, length]`.
    pub fn point_at(&self, s: f64) -> Vector3<f64> {
        match self.locate(s) {
            Some((i, t)) => self.points[i] + (self.points[i + 1] - self.points[i]) * t,
            None => self.points.first().copied().unwrap_or_else(Vector3::zeros),
        }
    }

    /// Unit direction of the segment at arc length `s` (clamped as in [`PlannedPath::point_at`]);
    /// at a vertex, the segment that leaves it, and at the goal the last segment. Zero for a path
    /// without length.
    pub fn tangent_at(&self, s: f64) -> Vector3<f64> {
        match self.locate(s) {
            Some((i, _)) => (self.points[i + 1] - self.points[i]).normalize(),
            None => Vector3::zeros(),
        }
    }

    /// The segment holding arc length `s` (index of its first vertex, skipping zero-length
    /// segments) and the fraction along it; `None` if the path has no length.
    fn locate(&self, s: f64) -> Option<(usize, f64)> {
        let mut last = None;
        let mut acc = 0.0;
        let s = if s.is_nan() { 0.0 } else { s.max(0.0) };
        for (i, w) in self.points.windows(2).enumerate() {
            let len = (w[1] - w[0]).norm();
            if len == 0.0 {
                continue;
            }
            if s < acc + len {
                return Some((i, (s - acc) / len));
            }
            acc += len;
            last = Some((i, 1.0));
        }
        last
    }
}

/// The radius the planner keeps free around the body centre, metres: the body's half-diagonal
/// `|half_extents|` (the box fits in that ball in any orientation) plus `margin`.
pub fn required_clearance(half_extents: Vector3<f32>, margin: f64) -> f64 {
    half_extents.cast::<f64>().norm() + margin
}

/// Whether `p` can be a flight's start or goal (`which`) in a field whose grid spans `grid`, as
/// far as the grid alone says: the body (of `half_extents`, in any orientation) inside the grid,
/// the centre inside the altitude band. [`plan`] checks the same and the clearance from
/// geometry; this check needs no field, so a config is checked before any field is built.
pub fn check_placement(
    which: &'static str,
    p: &Vector3<f64>,
    grid: &nerfsv_scene::Aabb,
    half_extents: Vector3<f32>,
    cfg: &PlannerConfig,
) -> Result<(), PlanError> {
    let (usable_min, usable_max) = usable_box(grid, half_extents.cast::<f64>().norm());
    placement(which, p, usable_min, usable_max, cfg.altitude)
}

/// The box the body centre must stay in for a body of radius `body_radius` to stay in `grid`.
fn usable_box(grid: &nerfsv_scene::Aabb, body_radius: f64) -> (Vector3<f64>, Vector3<f64>) {
    (grid.min.coords.cast::<f64>().add_scalar(body_radius), grid.max.coords.cast::<f64>().add_scalar(-body_radius))
}

fn placement(
    which: &'static str,
    p: &Vector3<f64>,
    usable_min: Vector3<f64>,
    usable_max: Vector3<f64>,
    band: [f64; 2],
) -> Result<(), PlanError> {
    if !(0..3).all(|a| p[a] >= usable_min[a] && p[a] <= usable_max[a]) {
        return Err(PlanError::OutsideGrid { which, point: *p, usable_min, usable_max });
    }
    if !(p.z >= band[0] && p.z <= band[1]) {
        return Err(PlanError::OutsideAltitude { which, z: p.z, band });
    }
    Ok(())
}

/// Why no path could be planned.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error(transparent)]
    Invalid(#[from] InvalidValue),
    /// The point (with the body around it) is not inside the field's grid.
    #[error(
        "{which} {} is outside the collision grid: the body centre must lie within {} to {}",
        P(point),
        P(usable_min),
        P(usable_max)
    )]
    OutsideGrid { which: &'static str, point: Vector3<f64>, usable_min: Vector3<f64>, usable_max: Vector3<f64> },
    /// The point's altitude is outside the planner's band.
    #[error("{which} is at altitude {z:.3} m, outside the flight band [{}, {}] m", band[0], band[1])]
    OutsideAltitude { which: &'static str, z: f64, band: [f64; 2] },
    /// The point is too close to geometry (or inside it) for the body.
    #[error("{which} {} {}; the body needs {required:.3} m", P(point), Clearance(*distance))]
    Blocked { which: &'static str, point: Vector3<f64>, distance: f64, required: f64 },
    /// Start and goal are not connected through usable space.
    #[error("no path from {} to {} keeps {required:.3} m from geometry inside the altitude band", P(start), P(goal))]
    NoPath { start: Vector3<f64>, goal: Vector3<f64>, required: f64 },
}

/// A point printed as `(0.39, -0.67, 0.20)`.
struct P<'a>(&'a Vector3<f64>);

impl fmt::Display for P<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "({:.2}, {:.2}, {:.2})", self.0.x, self.0.y, self.0.z)
    }
}

/// "is 0.031 m from geometry", or "is inside geometry (0.020 m deep)".
struct Clearance(f64);

impl fmt::Display for Clearance {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0 < 0.0 {
            write!(f, "is inside geometry ({:.3} m deep)", -self.0)
        } else {
            write!(f, "is {:.3} m from geometry", self.0)
        }
    }
}

/// Plans a path for a body of `half_extents` (metres, body frame) from `start` to `goal` through
/// `field`; see the module docs for the method and what the result guarantees.
pub fn plan(
    field: &SdfGrid,
    start: Vector3<f64>,
    goal: Vector3<f64>,
    half_extents: Vector3<f32>,
    cfg: &PlannerConfig,
) -> Result<PlannedPath, PlanError> {
    cfg.validate().map_err(|e| e.within("planner"))?;
    for (a, name) in ["half_extents.x", "half_extents.y", "half_extents.z"].iter().enumerate() {
        non_negative(name, half_extents[a] as f64)?;
    }
    let space = Space::new(field, required_clearance(half_extents, cfg.margin), half_extents.cast::<f64>().norm(), cfg);
    for (which, p) in [("start", start), ("goal", goal)] {
        space.check_endpoint(which, &p)?;
    }
    if space.segment_is_clear(&start, &goal) {
        return Ok(PlannedPath { points: vec![start, goal] });
    }
    let no_path = || PlanError::NoPath { start, goal, required: space.required };
    let s_node = space.nearest_connected_node(&start).ok_or_else(no_path)?;
    let g_node = space.nearest_connected_node(&goal).ok_or_else(no_path)?;
    let nodes = space.astar(s_node, g_node).ok_or_else(no_path)?;
    let mut points = vec![start];
    points.extend(nodes.iter().map(|&n| space.node_position(n)));
    points.push(goal);
    points.dedup();
    Ok(PlannedPath { points: space.shortcut(&points) })
}

/// The usable part of the grid: the node layers inside the altitude band and the body box.
struct Space<'a> {
    field: &'a SdfGrid,
    required: f64,
    band: [f64; 2],
    /// Box the body centre must stay in so the body stays in the grid.
    usable_min: Vector3<f64>,
    usable_max: Vector3<f64>,
    /// First node index and node count per axis of the searched sub-grid.
    lo: [usize; 3],
    n: [usize; 3],
    /// Per searched node (x fastest): usable or not.
    usable: Vec<bool>,
    /// Sampling step along segments, metres.
    sample_step: f64,
}

impl<'a> Space<'a> {
    fn new(field: &'a SdfGrid, required: f64, body_radius: f64, cfg: &PlannerConfig) -> Self {
        let g = &field.geometry;
        let (usable_min, usable_max) = usable_box(&g.bounds(), body_radius);
        let lo_v = Vector3::new(usable_min.x, usable_min.y, usable_min.z.max(cfg.altitude[0]));
        let hi_v = Vector3::new(usable_max.x, usable_max.y, usable_max.z.min(cfg.altitude[1]));
        let cell = g.cell as f64;
        let origin = g.origin.coords.cast::<f64>();
        let mut lo = [0usize; 3];
        let mut n = [0usize; 3];
        for a in 0..3 {
            let first = ((lo_v[a] - origin[a]) / cell - 1e-9).ceil().max(0.0);
            let last = ((hi_v[a] - origin[a]) / cell + 1e-9).floor().min((g.dims[a] - 1) as f64);
            lo[a] = first as usize;
            n[a] = if last >= first { (last - first) as usize + 1 } else { 0 };
        }
        let mut usable = vec![false; n[0] * n[1] * n[2]];
        for k in 0..n[2] {
            for j in 0..n[1] {
                for i in 0..n[0] {
                    let d = field.get(lo[0] + i, lo[1] + j, lo[2] + k) as f64;
                    usable[i + n[0] * (j + n[1] * k)] = d >= required;
                }
            }
        }
        Self { field, required, band: cfg.altitude, usable_min, usable_max, lo, n, usable, sample_step: cell / 8.0 }
    }

    fn in_box(&self, p: &Vector3<f64>) -> bool {
        (0..3).all(|a| p[a] >= self.usable_min[a] && p[a] <= self.usable_max[a])
    }

    fn distance(&self, p: &Vector3<f64>) -> Option<f64> {
        let q = Point3::new(p.x as f32, p.y as f32, p.z as f32);
        self.field.distance(q).in_grid().map(|d| d as f64)
    }

    /// In the body box, in the band, and far enough from geometry.
    fn point_is_usable(&self, p: &Vector3<f64>) -> bool {
        self.in_box(p)
            && p.z >= self.band[0]
            && p.z <= self.band[1]
            && self.distance(p).is_some_and(|d| d >= self.required)
    }

    fn check_endpoint(&self, which: &'static str, p: &Vector3<f64>) -> Result<(), PlanError> {
        placement(which, p, self.usable_min, self.usable_max, self.band)?;
        let distance = self.distance(p).unwrap_or(f64::NEG_INFINITY);
        if distance < self.required {
            return Err(PlanError::Blocked { which, point: *p, distance, required: self.required });
        }
        Ok(())
    }

    /// Usable at both ends and at samples at most ⅛ cell apart between them.
    fn segment_is_clear(&self, a: &Vector3<f64>, b: &Vector3<f64>) -> bool {
        let len = (b - a).norm();
        let steps = (len / self.sample_step).ceil().max(1.0) as usize;
        (0..=steps).all(|i| self.point_is_usable(&a.lerp(b, i as f64 / steps as f64)))
    }

    fn node_index(&self, c: [usize; 3]) -> usize {
        c[0] + self.n[0] * (c[1] + self.n[1] * c[2])
    }

    fn node_coords(&self, idx: usize) -> [usize; 3] {
        [idx % self.n[0], (idx / self.n[0]) % self.n[1], idx / (self.n[0] * self.n[1])]
    }

    fn node_position(&self, idx: usize) -> Vector3<f64> {
        let c = self.node_coords(idx);
        let g = &self.field.geometry;
        g.position_of(self.lo[0] + c[0], self.lo[1] + c[1], self.lo[2] + c[2]).coords.cast::<f64>()
    }

    /// The usable node nearest to `p` joined to it by a clear segment, searched in cubes of
    /// growing radius (up to 8 cells); ties go to the lower index.
    fn nearest_connected_node(&self, p: &Vector3<f64>) -> Option<usize> {
        if self.usable.is_empty() {
            return None;
        }
        let g = &self.field.geometry;
        let cell = g.cell as f64;
        let origin = g.origin.coords.cast::<f64>();
        let centre: [i64; 3] = std::array::from_fn(|a| ((p[a] - origin[a]) / cell).round() as i64 - self.lo[a] as i64);
        for r in [2i64, 4, 8] {
            let mut candidates: Vec<(f64, usize)> = Vec::new();
            for dk in -r..=r {
                for dj in -r..=r {
                    for di in -r..=r {
                        let c = [centre[0] + di, centre[1] + dj, centre[2] + dk];
                        if (0..3).any(|a| c[a] < 0 || c[a] >= self.n[a] as i64) {
                            continue;
                        }
                        let idx = self.node_index([c[0] as usize, c[1] as usize, c[2] as usize]);
                        if self.usable[idx] {
                            candidates.push(((self.node_position(idx) - p).norm(), idx));
                        }
                    }
                }
            }
            candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            if let Some(&(_, idx)) =
                candidates.iter().find(|(_, idx)| self.segment_is_clear(p, &self.node_position(*idx)))
            {
                return Some(idx);
            }
        }
        None
    }

    /// Whether the move from node `c` by `d` (each −1, 0 or 1) stays usable: every node of the
    /// box spanned by the two ends is usable (the trilinear field inside is a convex
    /// combination of them).
    fn move_is_clear(&self, c: [usize; 3], d: [i64; 3]) -> bool {
        let range = |a: usize| {
            let other = (c[a] as i64 + d[a]) as usize;
            c[a].min(other)..=c[a].max(other)
        };
        for k in range(2) {
            for j in range(1) {
                for i in range(0) {
                    if !self.usable[self.node_index([i, j, k])] {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// A* over usable nodes from `from` to `to`: node indices of a shortest 26-connected path.
    fn astar(&self, from: usize, to: usize) -> Option<Vec<usize>> {
        let cell = self.field.geometry.cell as f64;
        let goal = self.node_coords(to);
        let h = |c: [usize; 3]| {
            let d = Vector3::from_fn(|a, _| c[a] as f64 - goal[a] as f64);
            d.norm() * cell
        };
        let mut offsets = Vec::with_capacity(26);
        for dk in -1i64..=1 {
            for dj in -1i64..=1 {
                for di in -1i64..=1 {
                    if (di, dj, dk) != (0, 0, 0) {
                        let len = ((di * di + dj * dj + dk * dk) as f64).sqrt() * cell;
                        offsets.push(([di, dj, dk], len));
                    }
                }
            }
        }
        let total = self.usable.len();
        let mut g_cost = vec![f64::INFINITY; total];
        let mut parent = vec![u32::MAX; total];
        let mut closed = vec![false; total];
        let mut open = BinaryHeap::new();
        g_cost[from] = 0.0;
        open.push(Open { f: h(self.node_coords(from)), g: 0.0, idx: from });
        while let Some(Open { g, idx, .. }) = open.pop() {
            if closed[idx] {
                continue;
            }
            closed[idx] = true;
            if idx == to {
                let mut nodes = vec![to];
                let mut cur = to;
                while cur != from {
                    cur = parent[cur] as usize;
                    nodes.push(cur);
                }
                nodes.reverse();
                return Some(nodes);
            }
            let c = self.node_coords(idx);
            for &(d, len) in &offsets {
                let nc: [i64; 3] = std::array::from_fn(|a| c[a] as i64 + d[a]);
                if (0..3).any(|a| nc[a] < 0 || nc[a] >= self.n[a] as i64) {
                    continue;
                }
                let nc = [nc[0] as usize, nc[1] as usize, nc[2] as usize];
                let nidx = self.node_index(nc);
                if closed[nidx] || !self.usable[nidx] {
                    continue;
                }
                let ng = g + len;
                if ng < g_cost[nidx] && self.move_is_clear(c, d) {
                    g_cost[nidx] = ng;
                    parent[nidx] = idx as u32;
                    open.push(Open { f: ng + h(nc), g: ng, idx: nidx });
                }
            }
        }
        None
    }

    /// Greedy shortcutting: from each kept point, the farthest later point joined by a clear
    /// segment (consecutive points of the input are always joined, so this always advances).
    fn shortcut(&self, points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let mut out = vec![points[0]];
        let mut i = 0;
        while i + 1 < points.len() {
            let next =
                (i + 2..points.len()).rev().find(|&j| self.segment_is_clear(&points[i], &points[j])).unwrap_or(i + 1);
            out.push(points[next]);
            i = next;
        }
        out
    }
}

/// An open A* node: lowest `f` first, then highest `g` (deeper first), then lowest index.
#[derive(Clone, Copy, Debug)]
struct Open {
    f: f64,
    g: f64,
    idx: usize,
}

impl PartialEq for Open {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for Open {}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Open {
    /// Reversed so that `BinaryHeap` (a max-heap) pops the best node.
    fn cmp(&self, other: &Self) -> Ordering {
        other.f.total_cmp(&self.f).then(self.g.total_cmp(&other.g)).then(other.idx.cmp(&self.idx))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(points: &[[f64; 3]]) -> PlannedPath {
        PlannedPath { points: points.iter().map(|&p| Vector3::from(p)).collect() }
    }

    #[test]
    fn arc_length_queries_clamp_and_skip_zero_length_segments() {
        let p = path(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0]]);
        assert_eq!(p.length(), 3.0);
        assert_eq!(p.point_at(-1.0), Vector3::zeros());
        assert_eq!(p.point_at(0.5), Vector3::new(0.5, 0.0, 0.0));
        assert_eq!(p.point_at(2.0), Vector3::new(1.0, 1.0, 0.0));
        assert_eq!(p.point_at(9.0), Vector3::new(1.0, 2.0, 0.0));
        assert_eq!(p.tangent_at(0.999), Vector3::x());
        assert_eq!(p.tangent_at(1.0), Vector3::y());
        assert_eq!(p.tangent_at(3.0), Vector3::y());
        let single = path(&[[0.5, 0.5, 0.5]]);
        assert_eq!(single.point_at(1.0), Vector3::repeat(0.5));
        assert_eq!(single.tangent_at(0.0), Vector3::zeros());
    }

    #[test]
    fn config_values_are_refused_with_their_field() {
        let e = PlannerConfig { margin: -0.1, ..Default::default() }.validate().unwrap_err();
        assert_eq!(e.field, "margin");
        let e = PlannerConfig { altitude: [0.5, 0.1], ..Default::default() }.validate().unwrap_err();
        assert_eq!(e.field, "altitude[1]");
        assert!(PlannerConfig::default().validate().is_ok());
    }
}
