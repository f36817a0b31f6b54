//! Marching-cubes lookup tables in the Lorensen–Cline / Bourke layout.
//!
//! Corner `c` of a cube has offset [`CORNERS`]`[c]` (Bourke's numbering: 0 (0,0,0), 1 (1,0,0),
//! 2 (1,1,0), 3 (0,1,0), then the same at z = 1). Edge `e` joins corners [`EDGE_CORNERS`]`[e]`.
//! The case index has bit `c` set when corner `c` is **inside**. [`EDGE_TABLE`]`[case]` has bit `e`
//! set when edge `e` crosses the surface, and [`TRI_TABLE`]`[case]` lists up to five triangles
//! as edge triples, terminated by −1.
//!
//! The tables are generated, not transcribed (see `generate` in the tests, which also checks these
//! constants against it): on each cube face the surface contour joins the crossed edges, and on an
//! ambiguous face (diagonal corners alike) it cuts off each *inside* corner separately. Because that
//! decision depends on the face's four corners only, two cubes sharing a face agree and the
//! surface is watertight. Each contour loop is fanned into triangles wound counter-clockwise seen
//! from outside, so normals point from inside to outside. The edge table equals Bourke's
//! (it depends only on which corners are inside).

/// Corner offsets `(dx, dy, dz)` of the unit cube, Bourke's numbering.
pub const CORNERS: [[usize; 3]; 8] = [
    [0, 0, 0],
    [1, 0, 0],
    [1, 1, 0],
    [0, 1, 0],
    [0, 0, 1],
    [1, 0, 1],
    [1, 1, 1],
    [0, 1, 1],
];

/// The two corners joined by each of the 12 edges.
pub const EDGE_CORNERS: [[usize; 2]; 12] = [
    [0, 1],
    [1, 2],
    [2, 3],
    [3, 0],
    [4, 5],
    [5, 6],
    [6, 7],
    [7, 4],
    [0, 4],
    [1, 5],
    [2, 6],
    [3, 7],
];

/// Each edge as (offset of its lower-coordinate corner, axis 0/1/2): the grid edge it lies on.
pub const EDGE_GRID: [([usize; 3], usize); 12] = [
    ([0, 0, 0], 0),
    ([1, 0, 0], 1),
    ([0, 1, 0], 0),
    ([0, 0, 0], 1),
    ([0, 0, 1], 0),
    ([1, 0, 1], 1),
    ([0, 1, 1], 0),
    ([0, 0, 1], 1),
    ([0, 0, 0], 2),
    ([1, 0, 0], 2),
    ([1, 1, 0], 2),
    ([0, 1, 0], 2),
];

include!("mc_tables_data.rs");

#[cfg(test)]
pub(crate) mod generator {
    use super::*;

    type V = [f32; 3];

    fn sub(a: V, b: V) -> V {
        [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
    }

    fn cross(a: V, b: V) -> V {
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    }

    fn dot(a: V, b: V) -> f32 {
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    }

    fn corner(c: usize) -> V {
        CORNERS[c].map(|v| v as f32)
    }

    fn edge_between(a: usize, b: usize) -> usize {
        EDGE_CORNERS
            .iter()
            .position(|&[p, q]| (p == a && q == b) || (p == b && q == a))
            .expect("corners share an edge")
    }

    fn midpoint(e: usize) -> V {
        let [a, b] = EDGE_CORNERS[e];
        let (pa, pb) = (corner(a), corner(b));
        [(pa[0] + pb[0]) / 2.0, (pa[1] + pb[1]) / 2.0, (pa[2] + pb[2]) / 2.0]
    }

    /// Faces as corner cycles with outward normals.
    const FACES: [([usize; 4], V); 6] = [
        ([0, 1, 2, 3], [0.0, 0.0, -1.0]),
        ([4, 5, 6, 7], [0.0, 0.0, 1.0]),
        ([0, 1, 5, 4], [0.0, -1.0, 0.0]),
        ([3, 2, 6, 7], [0.0, 1.0, 0.0]),
        ([0, 3, 7, 4], [-1.0, 0.0, 0.0]),
        ([1, 2, 6, 5], [1.0, 0.0, 0.0]),
    ];

    /// Triangles (edge triples, outward winding) for one case.
    pub(crate) fn triangles(case: usize) -> Vec<[usize; 3]> {
        let inside = |c: usize| case & (1 << c) != 0;
        // next[e] = the edge after e along its contour loop.
        let mut next = [usize::MAX; 12];
        for (f, normal) in FACES {
            let crossed: Vec<usize> =
                (0..4).filter(|&i| inside(f[i]) != inside(f[(i + 1) % 4])).collect();
            let mut segments: Vec<(usize, usize, usize)> = Vec::new(); // (edge a, edge b, ref corner)
            match crossed.len() {
                0 => {}
                2 => {
                    let e = |i: usize| edge_between(f[i], f[(i + 1) % 4]);
                    let reference = *f.iter().find(|&&c| inside(c)).unwrap();
                    segments.push((e(crossed[0]), e(crossed[1]), reference));
                }
                4 => {
                    // Ambiguous face: cut off each inside corner on its own.
                    for i in 0..4 {
                        if inside(f[i]) {
                            let prev = edge_between(f[(i + 3) % 4], f[i]);
                            let nxt = edge_between(f[i], f[(i + 1) % 4]);
                            segments.push((prev, nxt, f[i]));
                        }
                    }
                }
                n => unreachable!("a face has an even number of crossings, got {n}"),
            }
            for (a, b, reference) in segments {
                // Orient a → b so the inside corner is on the left, seen from outside the face.
                let (pa, pb) = (midpoint(a), midpoint(b));
                let turn = dot(cross(sub(pb, pa), sub(corner(reference), pa)), normal);
                let (a, b) = if turn > 0.0 { (a, b) } else { (b, a) };
                assert_eq!(next[a], usize::MAX, "case {case}: edge {a} leaves twice");
                next[a] = b;
            }
        }
        let mut visited = [false; 12];
        let mut tris = Vec::new();
        for start in 0..12 {
            if next[start] == usize::MAX || visited[start] {
                continue;
            }
            let mut lp = vec![start];
            visited[start] = true;
            let mut e = next[start];
            while e != start {
                visited[e] = true;
                lp.push(e);
                e = next[e];
            }
            // The loop runs counter-clockwise around the inside corners seen from outside the
            // cube, i.e. clockwise seen from the outside of the surface: reverse the fan.
            for i in 1..lp.len() - 1 {
                tris.push([lp[0], lp[i + 1], lp[i]]);
            }
        }
        tris
    }

    /// The two tables as Rust source, for `mc_tables_data.rs`.
    pub(crate) fn source() -> String {
        let mut s = String::from(
            "// Generated by `cargo test -p nerfsv-collision -- --ignored print_mc_tables`;\n\
             // checked by `mc_tables_match_their_generator`. Do not edit by hand.\n\n\
             /// Bit `e` set when edge `e` crosses the surface, per case.\n\
             #[rustfmt::skip]\npub const EDGE_TABLE: [u16; 256] = [\n",
        );
        for row in 0..32 {
            s.push_str("   ");
            for case in row * 8..row * 8 + 8 {
                let bits = triangles(case).iter().flatten().fold(0u16, |m, &e| m | (1 << e));
                s.push_str(&format!(" 0x{bits:03x},"));
            }
            s.push('\n');
        }
        s.push_str(
            "];\n\n/// Up to five triangles per case, as edge triples, terminated by -1.\n\
             #[rustfmt::skip]\npub const TRI_TABLE: [[i8; 16]; 256] = [\n",
        );
        for case in 0..256 {
            let mut row = [-1i32; 16];
            for (i, &e) in triangles(case).iter().flatten().enumerate() {
                row[i] = e as i32;
            }
            let items: Vec<String> = row.iter().map(|v| v.to_string()).collect();
            s.push_str(&format!("    [{}],\n", items.join(", ")));
        }
        s.push_str("];\n");
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[ignore = "prints the generated tables for mc_tables_data.rs"]
    fn print_mc_tables() {
        print!("{}", generator::source());
    }

    #[test]
    fn mc_tables_match_their_generator() {
        for case in 0..256 {
            let tris = generator::triangles(case);
            assert!(tris.len() <= 5, "case {case} has {} triangles", tris.len());
            let mut row = [-1i8; 16];
            for (i, &e) in tris.iter().flatten().enumerate() {
                row[i] = e as i8;
            }
            assert_eq!(TRI_TABLE[case], row, "case {case}");
            let bits = (0..12)
                .filter(|&e| {
                    let [a, b] = EDGE_CORNERS[e];
                    (case >> a & 1) != (case >> b & 1)
                })
                .fold(0u16, |m, e| m | (1 << e));
            assert_eq!(EDGE_TABLE[case], bits, "case {case}");
        }
    }

    #[test]
    fn edge_table_starts_like_bourkes() {
        // Bourke's first entries: 0x0, 0x109, 0x203, 0x30a, 0x406, 0x50f.
        assert_eq!(EDGE_TABLE[..6], [0x000, 0x109, 0x203, 0x30a, 0x406, 0x50f]);
        assert_eq!(TRI_TABLE[0][0], -1);
        assert_eq!(TRI_TABLE[255][0], -1);
    }
}
