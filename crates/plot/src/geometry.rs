//! Plane geometry the figures need: clipping polylines to the view, arc length along a track,
//! projecting a point onto a track, and the zero contour of a sampled field (marching squares).

/// An axis-aligned window in world units: `x[0] ≤ x ≤ x[1]`, `y[0] ≤ y ≤ y[1]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Window {
    pub x: [f64; 2],
    pub y: [f64; 2],
}

impl Window {
    pub fn contains(&self, p: [f64; 2]) -> bool {
        p[0] >= self.x[0] && p[0] <= self.x[1] && p[1] >= self.y[0] && p[1] <= self.y[1]
    }
}

/// The part of segment `a → b` inside `win` (Liang–Barsky). Ends that need no clipping are
/// returned bit-exact, so consecutive clipped segments of a polyline still join.
pub(crate) fn clip_segment(a: [f64; 2], b: [f64; 2], win: &Window) -> Option<([f64; 2], [f64; 2])> {
    let d = [b[0] - a[0], b[1] - a[1]];
    let (mut t0, mut t1) = (0.0_f64, 1.0_f64);
    // Each pair (p, q): the segment is inside where p·t ≤ q.
    let edges = [(-d[0], a[0] - win.x[0]), (d[0], win.x[1] - a[0]), (-d[1], a[1] - win.y[0]), (d[1], win.y[1] - a[1])];
    for (p, q) in edges {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    if t0 > t1 {
        return None;
    }
    let at = |t: f64| {
        if t == 0.0 {
            a
        } else if t == 1.0 {
            b
        } else {
            [a[0] + d[0] * t, a[1] + d[1] * t]
        }
    };
    Some((at(t0), at(t1)))
}

/// Splits a polyline into the pieces that lie inside `win`. `None` vertices (non-finite data)
/// break the line.
pub(crate) fn clip_polyline(points: impl IntoIterator<Item = Option<[f64; 2]>>, win: &Window) -> Vec<Vec<[f64; 2]>> {
    let mut pieces: Vec<Vec<[f64; 2]>> = Vec::new();
    let mut current: Vec<[f64; 2]> = Vec::new();
    let mut prev: Option<[f64; 2]> = None;
    let flush = |current: &mut Vec<[f64; 2]>, pieces: &mut Vec<Vec<[f64; 2]>>| {
        if !current.is_empty() {
            pieces.push(std::mem::take(current));
        }
    };
    for p in points {
        match (prev, p) {
            (Some(a), Some(b)) => match clip_segment(a, b, win) {
                Some((ca, cb)) => {
                    if current.last() != Some(&ca) {
                        flush(&mut current, &mut pieces);
                        current.push(ca);
                    }
                    current.push(cb);
                }
                None => flush(&mut current, &mut pieces),
            },
            (None, Some(b)) => {
                flush(&mut current, &mut pieces);
                if win.contains(b) {
                    current.push(b);
                }
            }
            (_, None) => flush(&mut current, &mut pieces),
        }
        prev = p;
    }
    flush(&mut current, &mut pieces);
    pieces
}

/// A point with all coordinates finite, else `None`.
pub(crate) fn finite3(p: [f64; 3]) -> Option<[f64; 3]> {
    p.iter().all(|v| v.is_finite()).then_some(p)
}

/// Horizontal (xy) arc length travelled up to each vertex; `None` for non-finite vertices,
/// which are skipped (the distance runs on from the previous finite vertex).
pub(crate) fn xy_arc_length(points: &[[f64; 3]]) -> Vec<Option<f64>> {
    let mut s = 0.0;
    let mut prev: Option<[f64; 3]> = None;
    points
        .iter()
        .map(|&p| {
            let p = finite3(p)?;
            if let Some(q) = prev {
                s += (p[0] - q[0]).hypot(p[1] - q[1]);
            }
            prev = Some(p);
            Some(s)
        })
        .collect()
}

/// The point of the polyline nearest to `q` in 3-D: returns (xy arc length there, distance).
pub(crate) fn project_onto_track(points: &[[f64; 3]], q: [f64; 3]) -> Option<(f64, f64)> {
    let s = xy_arc_length(points);
    let finite: Vec<([f64; 3], f64)> = points.iter().zip(&s).filter_map(|(&p, &s)| Some((p, s?))).collect();
    let dist =
        |a: [f64; 3], b: [f64; 3]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    let mut best: Option<(f64, f64)> = finite.first().map(|&(p, s)| (s, dist(p, q)));
    for w in finite.windows(2) {
        let ((a, sa), (b, sb)) = (w[0], w[1]);
        let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let len2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        let t = if len2 > 0.0 {
            (((q[0] - a[0]) * d[0] + (q[1] - a[1]) * d[1] + (q[2] - a[2]) * d[2]) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let p = [a[0] + d[0] * t, a[1] + d[1] * t, a[2] + d[2] * t];
        let dp = dist(p, q);
        if best.is_none_or(|(_, bd)| dp < bd) {
            best = Some((sa + (sb - sa) * t, dp));
        }
    }
    best
}

/// Segments of the zero level set of a node-sampled field (marching squares), restricted to
/// cells that meet `win`. `node(i, j)` is the value at `origin + cell·(i, j)`; NaN nodes end
/// the contour. Inside is `value < 0`, as in [`crate::FieldSlice`].
pub(crate) fn zero_contour(
    origin: [f64; 2],
    cell: f64,
    dims: [usize; 2],
    node: impl Fn(usize, usize) -> f64,
    win: &Window,
) -> Vec<([f64; 2], [f64; 2])> {
    let mut segments = Vec::new();
    if dims[0] < 2 || dims[1] < 2 {
        return segments;
    }
    let index_range = |lo: f64, hi: f64, o: f64, n: usize| {
        let a = ((lo - o) / cell).floor().max(0.0) as usize;
        let b = (((hi - o) / cell).ceil().max(0.0) as usize).min(n - 1);
        (a.min(n - 1), b)
    };
    let (i0, i1) = index_range(win.x[0], win.x[1], origin[0], dims[0]);
    let (j0, j1) = index_range(win.y[0], win.y[1], origin[1], dims[1]);
    let at = |i: usize, j: usize| [origin[0] + cell * i as f64, origin[1] + cell * j as f64];
    // Where the field crosses zero on the edge from node p (value a) to node q (value b).
    let cross = |p: [f64; 2], q: [f64; 2], a: f64, b: f64| {
        let t = a / (a - b);
        [p[0] + (q[0] - p[0]) * t, p[1] + (q[1] - p[1]) * t]
    };
    for j in j0..j1 {
        for i in i0..i1 {
            let v = [node(i, j), node(i + 1, j), node(i + 1, j + 1), node(i, j + 1)];
            if v.iter().any(|x| !x.is_finite()) {
                continue;
            }
            let inside = v.map(|x| x < 0.0);
            if inside.iter().all(|&b| b) || inside.iter().all(|&b| !b) {
                continue;
            }
            let p = [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)];
            // Crossings on edges 0: p0–p1 (bottom), 1: p1–p2 (right), 2: p2–p3 (top),
            // 3: p3–p0 (left).
            let edge = |e: usize| {
                let (a, b) = (e, (e + 1) % 4);
                (inside[a] != inside[b]).then(|| cross(p[a], p[b], v[a], v[b]))
            };
            let e: [Option<[f64; 2]>; 4] = [edge(0), edge(1), edge(2), edge(3)];
            let found: Vec<[f64; 2]> = e.iter().flatten().copied().collect();
            if found.len() == 2 {
                segments.push((found[0], found[1]));
            } else if let [Some(b), Some(r), Some(t), Some(l)] = e {
                // Saddle: the cell centre (mean of the nodes) decides which diagonal connects.
                let centre_inside = v.iter().sum::<f64>() / 4.0 < 0.0;
                if centre_inside == inside[0] {
                    // p0 and p2 connect: cut off corners p1 (bottom–right) and p3 (top–left).
                    segments.push((b, r));
                    segments.push((t, l));
                } else {
                    segments.push((b, l));
                    segments.push((r, t));
                }
            }
        }
    }
    segments
}

#[cfg(test)]
mod tests {
    use super::*;

    const UNIT: Window = Window { x: [0.0, 1.0], y: [0.0, 1.0] };

    #[test]
    fn clip_segment_cuts_at_the_window_edge_and_keeps_inner_ends_exact() {
        let (a, b) = clip_segment([0.5, 0.5], [1.5, 0.5], &UNIT).unwrap();
        assert_eq!(a, [0.5, 0.5]);
        assert!((b[0] - 1.0).abs() < 1e-12 && (b[1] - 0.5).abs() < 1e-12);
        assert!(clip_segment([1.5, 0.5], [2.0, 3.0], &UNIT).is_none());
        let (a, b) = clip_segment([-1.0, 0.5], [2.0, 0.5], &UNIT).unwrap();
        assert!((a[0] - 0.0).abs() < 1e-12 && (b[0] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn clip_polyline_splits_where_the_line_leaves_and_reenters() {
        let pts = [[0.2, 0.2], [0.8, 0.2], [1.5, 0.5], [0.8, 0.8], [0.2, 0.8]].map(Some);
        let pieces = clip_polyline(pts, &UNIT);
        assert_eq!(pieces.len(), 2);
        assert_eq!(pieces[0].len(), 3); // 0.2 → 0.8 → exit point
        assert_eq!(pieces[1].len(), 3); // entry point → 0.8 → 0.2
        let broken = clip_polyline([Some([0.1, 0.1]), None, Some([0.3, 0.3])], &UNIT);
        assert_eq!(broken.len(), 2);
    }

    #[test]
    fn arc_length_is_horizontal_and_skips_non_finite_points() {
        let s = xy_arc_length(&[[0.0, 0.0, 0.0], [3.0, 4.0, 9.0], [f64::NAN, 0.0, 0.0], [3.0, 5.0, 0.0]]);
        assert_eq!(s, vec![Some(0.0), Some(5.0), None, Some(6.0)]);
    }

    #[test]
    fn projection_finds_the_arc_length_of_the_nearest_point() {
        let track = [[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [2.0, 2.0, 1.0]];
        let (s, d) = project_onto_track(&track, [1.5, 0.1, 1.0]).unwrap();
        assert!((s - 1.5).abs() < 1e-12 && (d - 0.1).abs() < 1e-12);
        let (s, _) = project_onto_track(&track, [2.1, 1.0, 1.0]).unwrap();
        assert!((s - 3.0).abs() < 1e-12);
    }

    #[test]
    fn zero_contour_of_a_disc_lies_on_its_circle() {
        let (r, cell, n) = (0.5, 0.05, 41);
        let origin = [-1.0, -1.0];
        let node = |i: usize, j: usize| {
            let (x, y) = (origin[0] + cell * i as f64, origin[1] + cell * j as f64);
            x.hypot(y) - r
        };
        let win = Window { x: [-1.0, 1.0], y: [-1.0, 1.0] };
        let segs = zero_contour(origin, cell, [n, n], node, &win);
        // Perimeter 2πr ≈ 3.14 m at 0.05 m cells: about 60–90 segments.
        assert!(segs.len() > 50 && segs.len() < 120, "{} segments", segs.len());
        for (a, b) in segs {
            for p in [a, b] {
                // Linear interpolation of a cone is exact along axis-aligned edges to O(cell²/r).
                assert!((p[0].hypot(p[1]) - r).abs() < 0.01, "{p:?}");
            }
        }
    }
}
