//! Summaries the CLI prints as JSON, and agreement between two signed distance fields.

use rayon::prelude::*;

use crate::grid::GridGeometry;
use crate::mesh::Mesh;
use crate::occupancy::OccupancyGrid;
use crate::sdf::SdfGrid;

/// What a collision stage produced, for printing as JSON. Start from [`GridSummary::new`] and add
/// the parts at hand; absent parts are left out of the JSON.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GridSummary {
    /// Node counts `[nx, ny, nz]`.
    pub dims: [usize; 3],
    pub nodes: usize,
    /// Node spacing, metres.
    pub cell: f32,
    /// Node (0, 0, 0) and the last node, metres.
    pub origin: [f32; 3],
    pub max_corner: [f32; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub occupied_fraction: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sdf_min: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sdf_max: Option<f32>,
    /// Fraction of nodes with signed distance ≤ 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sdf_inside_fraction: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_vertices: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_triangles: Option<usize>,
    /// Mesh surface area, m².
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_area: Option<f64>,
}

impl GridSummary {
    pub fn new(geometry: &GridGeometry) -> Self {
        let b = geometry.bounds();
        Self {
            dims: geometry.dims,
            nodes: geometry.len(),
            cell: geometry.cell,
            origin: b.min.into(),
            max_corner: b.max.into(),
            occupied_fraction: None,
            sdf_min: None,
            sdf_max: None,
            sdf_inside_fraction: None,
            mesh_vertices: None,
            mesh_triangles: None,
            mesh_area: None,
        }
    }

    pub fn with_occupancy(mut self, occ: &OccupancyGrid) -> Self {
        self.occupied_fraction = Some(occ.occupied_fraction());
        self
    }

    pub fn with_sdf(mut self, sdf: &SdfGrid) -> Self {
        let (lo, hi) = sdf.min_max();
        self.sdf_min = Some(lo);
        self.sdf_max = Some(hi);
        let inside = sdf.data.par_iter().filter(|&&v| v <= 0.0).count();
        self.sdf_inside_fraction = Some(inside as f64 / sdf.data.len() as f64);
        self
    }

    pub fn with_mesh(mut self, mesh: &Mesh) -> Self {
        self.mesh_vertices = Some(mesh.vertices.len());
        self.mesh_triangles = Some(mesh.triangles.len());
        self.mesh_area = Some(mesh.area());
        self
    }
}

/// How well field `b` agrees with reference field `a` (e.g. NeRF-derived against ground truth).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Agreement {
    /// Nodes of `a` that were compared (those inside `b`'s grid).
    pub compared_nodes: usize,
    /// Intersection over union of the occupied sets `{sdf ≤ 0}` over all compared nodes
    /// (1 when both are empty).
    pub iou: f64,
    /// The z band, metres, and the compared nodes whose z lies in it (inclusive).
    pub z_band: (f32, f32),
    pub band_nodes: usize,
    /// Occupancy IoU within the band.
    pub band_iou: f64,
    /// Mean, 95th percentile (nearest rank) and maximum of `|sdf_a − sdf_b|` in the band,
    /// metres; `None` if the band holds no node.
    pub band_mean_abs_diff: Option<f64>,
    pub band_p95_abs_diff: Option<f32>,
    pub band_max_abs_diff: Option<f32>,
}

/// Compare `b` with `a` at the nodes of `a`. With the same geometry the node values are compared
/// directly; otherwise `b` is interpolated trilinearly at `a`'s nodes and nodes outside `b`'s grid
/// are skipped (see [`Agreement::compared_nodes`]).
pub fn agreement(a: &SdfGrid, b: &SdfGrid, z_band: (f32, f32)) -> Agreement {
    let g = a.geometry;
    let same = a.geometry == b.geometry;
    let [nx, ny, _] = g.dims;
    #[derive(Default)]
    struct Acc {
        compared: usize,
        inter: usize,
        union: usize,
        band_inter: usize,
        band_union: usize,
        diffs: Vec<f32>,
    }
    let acc = a
        .data
        .par_chunks(nx * ny)
        .enumerate()
        .fold(Acc::default, |mut acc, (k, slice)| {
            let z = g.position_of(0, 0, k).z;
            let in_band = z >= z_band.0 && z <= z_band.1;
            for j in 0..ny {
                for i in 0..nx {
                    let va = slice[i + nx * j];
                    let vb = if same {
                        b.data[g.index(i, j, k)]
                    } else {
                        match b.distance(g.position_of(i, j, k)).in_grid() {
                            Some(v) => v,
                            None => continue,
                        }
                    };
                    let (oa, ob) = (va <= 0.0, vb <= 0.0);
                    acc.compared += 1;
                    acc.inter += (oa && ob) as usize;
                    acc.union += (oa || ob) as usize;
                    if in_band {
                        acc.band_inter += (oa && ob) as usize;
                        acc.band_union += (oa || ob) as usize;
                        acc.diffs.push((va - vb).abs());
                    }
                }
            }
            acc
        })
        .reduce(Acc::default, |mut x, mut y| {
            x.compared += y.compared;
            x.inter += y.inter;
            x.union += y.union;
            x.band_inter += y.band_inter;
            x.band_union += y.band_union;
            x.diffs.append(&mut y.diffs);
            x
        });
    let ratio = |i: usize, u: usize| if u == 0 { 1.0 } else { i as f64 / u as f64 };
    let mut diffs = acc.diffs;
    let n = diffs.len();
    let (mean, p95, max) = if n == 0 {
        (None, None, None)
    } else {
        let mean = diffs.iter().map(|&d| d as f64).sum::<f64>() / n as f64;
        let max = diffs.iter().copied().fold(0f32, f32::max);
        let p95 = nerfsv_scene::stats::quantile_select(&mut diffs, 0.95);
        (Some(mean), Some(p95), Some(max))
    };
    Agreement {
        compared_nodes: acc.compared,
        iou: ratio(acc.inter, acc.union),
        z_band,
        band_nodes: n,
        band_iou: ratio(acc.band_inter, acc.band_union),
        band_mean_abs_diff: mean,
        band_p95_abs_diff: p95,
        band_max_abs_diff: max,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::ScalarGrid;
    use nerfsv_scene::Aabb;

    fn ball(r: f32, geometry: GridGeometry) -> SdfGrid {
        let grid = ScalarGrid::sample_geometry(geometry, |p| p.coords.norm() - r);
        SdfGrid::from_field(&grid, 0.0, true)
    }

    #[test]
    fn agreement_of_concentric_balls_matches_their_analytic_iou_and_offset() {
        let g = GridGeometry::covering(&Aabb::cube(0.5), 40.0).unwrap();
        let (a, b) = (ball(0.3, g), ball(0.25, g));
        let ag = agreement(&a, &b, (-0.11, 0.11));
        let iou = (0.25f64 / 0.3).powi(3);
        assert!((ag.iou - iou).abs() < 0.02, "iou {} vs {iou}", ag.iou);
        // |sdf_a − sdf_b| = 0.05 m exactly; each grid field is within ~0.2 cell of its sphere.
        assert!((ag.band_mean_abs_diff.unwrap() - 0.05).abs() < 0.0025, "{ag:?}");
        assert!((ag.band_p95_abs_diff.unwrap() - 0.05).abs() < 0.005, "{ag:?}");
        assert_eq!(ag.band_nodes, 9 * 41 * 41);
        assert_eq!(ag.compared_nodes, g.len());
        let same = agreement(&a, &a, (0.0, 0.1));
        assert_eq!((same.iou, same.band_max_abs_diff), (1.0, Some(0.0)));
    }

    #[test]
    fn agreement_resamples_a_field_on_another_grid() {
        let g = GridGeometry::covering(&Aabb::cube(0.5), 40.0).unwrap();
        let coarse = GridGeometry::covering(&Aabb::cube(0.4), 20.0).unwrap();
        let ag = agreement(&ball(0.3, g), &ball(0.3, coarse), (-0.1, 0.1));
        assert!(ag.compared_nodes < g.len() && ag.compared_nodes > 0);
        assert!(ag.iou > 0.97, "{ag:?}");
        assert!(ag.band_mean_abs_diff.unwrap() < 0.005, "{ag:?}");
        let json = serde_json::to_string(&GridSummary::new(&g).with_sdf(&ball(0.3, g))).unwrap();
        assert!(json.contains("\"dims\":[41,41,41]") && json.contains("sdf_min"), "{json}");
        assert!(!json.contains("mesh_triangles"));
        // Stored figures read back, absent parts included.
        let back: GridSummary = serde_json::from_str(&json).unwrap();
        assert_eq!(back, GridSummary::new(&g).with_sdf(&ball(0.3, g)));
        let back: Agreement = serde_json::from_str(&serde_json::to_string(&ag).unwrap()).unwrap();
        assert_eq!(back, ag);
    }
}
