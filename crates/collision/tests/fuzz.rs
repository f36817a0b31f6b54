//! Property tests: whatever bytes a grid file holds, [`SdfGrid::load`], [`ScalarGrid::load`]
//! and [`OccupancyGrid::load`] return, never panic and never abort on a crafted size, with
//! either an error that names the file or a grid whose data fits its geometry.
//!
//! Inputs start from real files of small grids of each kind and are mutated three ways:
//! consistently (metadata values replaced: dims like `100000,100000,100000`, NaN origins, zero
//! or huge cells; tensors renamed, retyped, reshaped or given non-finite values, re-serialised
//! as valid safetensors), through the raw header JSON (dtypes, shapes and offsets that need not
//! agree with the data), and byte by byte. Every file is read by all three loaders.
//!
//! Deterministic: a fixed seed, no persistence files.

use std::sync::OnceLock;

use nalgebra::Point3;
use nerfsv_collision::{GridGeometry, OccupancyGrid, ScalarGrid, SdfGrid};
use nerfsv_testkit::{
    check_error_names_file, config, f32_bits, mutated, mutation, retype, set_meta, HeaderEdit, Mutation, Parts,
};
use proptest::prelude::*;
use proptest::sample::Index;
use safetensors::tensor::Dtype;

/// Real files of a 3×4×5 grid of each kind: `[field, sdf, occupancy]`.
fn fixtures() -> &'static [Vec<u8>; 3] {
    static FILES: OnceLock<[Vec<u8>; 3]> = OnceLock::new();
    FILES.get_or_init(|| {
        let g = GridGeometry::new(Point3::new(-0.5, -0.25, 0.0), 0.25, [3, 4, 5]).unwrap();
        let data: Vec<f32> = (0..g.len()).map(|i| i as f32 * 0.1 - 1.0).collect();
        let dir = tempfile::tempdir().unwrap();
        let paths = ["field", "sdf", "occupancy"].map(|k| dir.path().join(format!("{k}.safetensors")));
        ScalarGrid { geometry: g, data: data.clone() }.save(&paths[0]).unwrap();
        SdfGrid::from_data(g, data.clone()).unwrap().save(&paths[1]).unwrap();
        OccupancyGrid { geometry: g, data: data.iter().map(|&v| v < 0.0).collect() }.save(&paths[2]).unwrap();
        paths.map(|p| std::fs::read(p).unwrap())
    })
}

// ---------------------------------------------------------------- random values

/// A metadata string: lists of numbers of every size, NaN, garbage.
fn meta_value() -> impl Strategy<Value = String> {
    let number = prop_oneof![
        3 => proptest::sample::select(vec![
            "0", "1", "2", "3", "4", "5", "-1", "0.25", "-0.5", "1e-45", "1e-30", "3e38", "3.5e38", "1e39", "NaN",
            "nan", "inf", "-inf", "100000", "65536", "4294967296", "18446744073709551615", "18446744073709551616",
            "", " ", "x", "1.5", "0x10",
        ])
        .prop_map(String::from),
        1 => any::<u32>().prop_map(|v| v.to_string()),
        1 => any::<f32>().prop_map(|v| v.to_string()),
    ];
    prop_oneof![
        3 => proptest::collection::vec(number.clone(), 3).prop_map(|v| v.join(",")),
        1 => proptest::collection::vec(number.clone(), 1..5).prop_map(|v| v.join(",")),
        2 => number,
        1 => proptest::sample::select(vec![
            "100000,100000,100000", "65536,65536,2", "3,4,5", "5,4,3", "3,4", "3,4,5,6", "3,,5", "3 ,4, 5",
            "field", "sdf", "occupancy", "nerfsv-grid", "1", "2",
        ])
        .prop_map(String::from),
        1 => "\\PC{0,12}",
    ]
}

/// Mostly the geometry's keys: the others only gate the file.
fn meta_key() -> impl Strategy<Value = &'static str> {
    prop_oneof![
        4 => proptest::sample::select(vec!["origin", "cell", "dims"]),
        1 => proptest::sample::select(vec!["format", "format_version", "kind", "extra"]),
    ]
}

fn dtype() -> impl Strategy<Value = Dtype> {
    proptest::sample::select(vec![Dtype::F32, Dtype::U8, Dtype::F16, Dtype::F64, Dtype::I32, Dtype::BOOL])
}

fn dim() -> impl Strategy<Value = usize> {
    prop_oneof![4 => 0..=6usize, 1 => proptest::sample::select(vec![16usize, 64, 256])]
}

// ---------------------------------------------------------------- mutations

#[derive(Clone, Debug)]
enum Edit {
    SetMeta(&'static str, String),
    RemoveMeta(&'static str),
    /// Renames the tensor (the kinds' names, or another).
    Rename(&'static str),
    /// Same bytes, another dtype (shape adjusted to the byte count when possible).
    Retype(Dtype),
    /// A new shape with matching data (each byte `fill`); with `match_dims` the metadata dims
    /// follow, a consistent grid of another size.
    Reshape(Vec<usize>, u8, bool),
    /// Sets one element's bytes (NaN, ±∞, 2, 255).
    Poke(Index, u32),
}

fn edit() -> impl Strategy<Value = Edit> {
    let bits = f32_bits(&[0xffff_ffff, 0x0202_0202]);
    prop_oneof![
        6 => (meta_key(), meta_value()).prop_map(|(k, v)| Edit::SetMeta(k, v)),
        1 => meta_key().prop_map(Edit::RemoveMeta),
        1 => proptest::sample::select(vec!["field", "sdf", "occupancy", "other", ""]).prop_map(Edit::Rename),
        1 => dtype().prop_map(Edit::Retype),
        3 => (proptest::collection::vec(dim(), 0..5), prop_oneof![Just(0u8), Just(1), any::<u8>()], any::<bool>())
            .prop_map(|(s, f, m)| Edit::Reshape(s, f, m)),
        3 => (any::<Index>(), bits).prop_map(|(i, b)| Edit::Poke(i, b)),
    ]
}

fn header_edit() -> impl Strategy<Value = HeaderEdit> {
    let field = proptest::sample::select(vec!["dtype", "shape", "data_offsets"]);
    let value = prop_oneof![
        proptest::sample::select(vec![
            "\"F32\"",
            "\"U8\"",
            "\"F16\"",
            "\"XX\"",
            "[5,4,3]",
            "[3,4,5]",
            "[0]",
            "[]",
            "[100000,100000,100000]",
            "[4294967296,4294967296,4294967296]",
            "[18446744073709551615,2,2]",
            "[0,0]",
            "[0,240]",
            "[240,0]",
            "[0,18446744073709551615]",
            "NaN",
            "null",
            "-1",
            "\"\"",
        ])
        .prop_map(String::from),
        (0..400u64, 0..400u64).prop_map(|(a, b)| format!("[{a},{b}]")),
        proptest::collection::vec(any::<u32>(), 0..4)
            .prop_map(|v| format!("[{}]", v.iter().map(u32::to_string).collect::<Vec<_>>().join(","))),
    ];
    prop_oneof![
        6 => (field, value).prop_map(|(f, v)| HeaderEdit::SetTensorField(None, f, v)),
        1 => prop_oneof![0..2_000u64, any::<u64>()].prop_map(HeaderEdit::Length),
    ]
}

/// Mostly consistent edits.
fn grid_mutation() -> impl Strategy<Value = Mutation<Edit>> {
    mutation([8, 1, 1], edit(), header_edit())
}

/// Applies `e` to the file's one tensor.
fn apply_edit(p: &mut Parts, e: &Edit) {
    let (name, dtype, shape, data) = &mut p.tensors[0];
    match e {
        Edit::SetMeta(k, v) => set_meta(p, k, v.clone()),
        Edit::RemoveMeta(k) => p.meta.retain(|(key, _)| key != k),
        Edit::Rename(n) => *name = n.to_string(),
        Edit::Retype(d) => retype(&mut p.tensors[0], *d),
        Edit::Reshape(s, fill, match_dims) => {
            let n: usize = s.iter().product();
            if n <= 1 << 16 {
                *data = vec![*fill; n * dtype.bitsize() / 8];
                *shape = s.clone();
                if *match_dims {
                    let dims: Vec<String> = s.iter().rev().map(usize::to_string).collect();
                    set_meta(p, "dims", dims.join(","));
                }
            }
        }
        Edit::Poke(i, bits) => {
            let size = (dtype.bitsize() / 8).max(1);
            if data.len() >= size {
                let k = i.index(data.len() / size) * size;
                let b = bits.to_le_bytes();
                for (j, byte) in data[k..k + size].iter_mut().enumerate() {
                    *byte = b[j % 4];
                }
            }
        }
    }
}

// ---------------------------------------------------------------- properties

/// A loaded geometry is usable: at least 2 nodes an axis, a positive finite cell, a finite
/// origin and far corner (so that queries never meet an infinite or NaN coordinate).
fn check_geometry(g: &GridGeometry, data_len: usize) -> Result<(), TestCaseError> {
    prop_assert!(g.dims.iter().all(|&n| n >= 2), "{g:?}");
    prop_assert!(g.cell.is_finite() && g.cell > 0.0, "{g:?}");
    prop_assert_eq!(data_len, g.len());
    let b = g.bounds();
    prop_assert!(b.min.iter().chain(b.max.iter()).all(|v| v.is_finite()), "{g:?}: bounds {b:?}");
    prop_assert!(g.diagonal().is_finite(), "{g:?}");
    Ok(())
}

/// Reads `bytes` with every grid loader.
fn check_all_loaders(bytes: &[u8]) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grid.safetensors");
    std::fs::write(&path, bytes).unwrap();
    match SdfGrid::load(&path) {
        Ok(g) => {
            check_geometry(&g.geometry, g.data.len())?;
            // Signed distances in metres: the format promises numbers.
            prop_assert!(g.data.iter().all(|v| v.is_finite()), "a non-finite distance");
            let c = g.geometry.bounds().center();
            let _ = (g.distance(c), g.gradient(c));
        }
        Err(e) => check_error_names_file(&e, &path)?,
    }
    match ScalarGrid::load(&path) {
        Ok(g) => check_geometry(&g.geometry, g.data.len())?,
        Err(e) => check_error_names_file(&e, &path)?,
    }
    match OccupancyGrid::load(&path) {
        Ok(g) => check_geometry(&g.geometry, g.data.len())?,
        Err(e) => check_error_names_file(&e, &path)?,
    }
    Ok(())
}

#[test]
fn the_unmutated_grid_files_load_and_are_valid() {
    for bytes in fixtures() {
        check_all_loaders(bytes).unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sdf.safetensors");
    std::fs::write(&path, &fixtures()[1]).unwrap();
    assert_eq!(SdfGrid::load(&path).unwrap().dims(), [3, 4, 5]);
}

proptest! {
    #![proptest_config(config(4096))]

    /// Consistent, header and byte mutations of the three kinds of grid file, each read by all
    /// three loaders: an error naming the file, or a grid whose data fits its geometry.
    #[test]
    fn mutated_grid_files_err_naming_the_file_or_load_valid(
        kind in 0..3usize,
        mutations in proptest::collection::vec(grid_mutation(), 1..3),
    ) {
        check_all_loaders(&mutated(&fixtures()[kind], &mutations, apply_edit))?;
    }
}
