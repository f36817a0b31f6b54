//! Files: grids as safetensors, the SDF as `.npy` (written atomically).
//!
//! A grid file is a safetensors file with one tensor of shape `[nz, ny, nx]` (so numpy/PyTorch
//! `t[z, y, x]` is node `(x, y, z)`) and this string metadata:
//!
//! | key | example | meaning |
//! |---|---|---|
//! | `format` | `nerfsv-grid` | file type |
//! | `format_version` | `1` | layout version |
//! | `kind` | `sdf` | `field` (F32), `sdf` (F32, metres, finite) or `occupancy` (U8, 0/1) |
//! | `origin` | `-1.9,-1.9,0` | node (0,0,0), metres |
//! | `cell` | `0.025` | node spacing, metres |
//! | `dims` | `153,153,49` | `nx,ny,nz` |
//!
//! The tensor is named like the kind. Floats are written in Rust's shortest round-trip form, so
//! a save/load round trip is bit-identical.

use std::collections::{BTreeMap, HashMap};
use std::io::Write;
use std::path::Path;

use nalgebra::Point3;
use nerfsv_scene::io::TensorBytes;
use safetensors::tensor::Dtype;
use safetensors::SafeTensors;

use crate::atomic::write_atomically;
use crate::grid::{GridGeometry, ScalarGrid};
use crate::occupancy::OccupancyGrid;
use crate::sdf::SdfGrid;
use crate::CollisionError;

const FORMAT: &str = "nerfsv-grid";
const FORMAT_VERSION: &str = "1";

fn f32_bytes(data: &[f32]) -> Vec<u8> {
    data.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn save_grid(
    path: &Path,
    kind: &'static str,
    geometry: &GridGeometry,
    dtype: Dtype,
    bytes: &[u8],
) -> Result<(), CollisionError> {
    let [nx, ny, nz] = geometry.dims;
    let o = geometry.origin;
    let metadata: BTreeMap<String, String> = [
        ("format", FORMAT.to_string()),
        ("format_version", FORMAT_VERSION.to_string()),
        ("kind", kind.to_string()),
        ("origin", format!("{},{},{}", o.x, o.y, o.z)),
        ("cell", format!("{}", geometry.cell)),
        ("dims", format!("{nx},{ny},{nz}")),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    let dtype = match dtype {
        Dtype::U8 => "U8",
        _ => "F32",
    };
    let tensor = TensorBytes { name: kind, dtype, shape: vec![nz, ny, nx], data: bytes };
    // Sorted header: the same grid always gives the same bytes.
    let buffer = nerfsv_scene::io::safetensors_bytes(&[tensor], &metadata);
    write_atomically(path, |w| w.write_all(&buffer))
}

fn bad(path: &Path, field: &'static str, found: &str, expected: &str) -> CollisionError {
    CollisionError::BadField {
        path: path.to_path_buf(),
        field,
        found: found.to_string(),
        expected: expected.to_string(),
    }
}

fn parse_list<T: std::str::FromStr>(
    path: &Path,
    field: &'static str,
    value: &str,
    expected: &str,
) -> Result<[T; 3], CollisionError> {
    let parts: Vec<&str> = value.split(',').map(str::trim).collect();
    let parsed: Option<Vec<T>> = parts.iter().map(|s| s.parse().ok()).collect();
    match parsed {
        Some(v) if v.len() == 3 => Ok(v.try_into().unwrap_or_else(|_| unreachable!())),
        _ => Err(bad(path, field, value, expected)),
    }
}

/// Read a grid file of `kind`, check its metadata and tensor, and return its geometry and the
/// tensor's raw little-endian bytes.
fn load_grid(path: &Path, kind: &'static str, dtype: Dtype) -> Result<(GridGeometry, Vec<u8>), CollisionError> {
    let p = || path.to_path_buf();
    let buffer = std::fs::read(path).map_err(|error| CollisionError::Io { path: p(), error })?;
    let st = SafeTensors::deserialize(&buffer).map_err(|error| CollisionError::SafeTensors { path: p(), error })?;
    let (_, header) =
        SafeTensors::read_metadata(&buffer).map_err(|error| CollisionError::SafeTensors { path: p(), error })?;
    let empty = HashMap::new();
    let meta = header.metadata().as_ref().unwrap_or(&empty);
    let field = |name: &'static str| {
        meta.get(name).map(String::as_str).ok_or(CollisionError::MissingField { path: p(), field: name })
    };
    let format = field("format")?;
    if format != FORMAT {
        return Err(bad(path, "format", format, &format!("\"{FORMAT}\"")));
    }
    let version = field("format_version")?;
    if version != FORMAT_VERSION {
        return Err(bad(path, "format_version", version, &format!("\"{FORMAT_VERSION}\"")));
    }
    let found_kind = field("kind")?;
    if found_kind != kind {
        return Err(bad(path, "kind", found_kind, &format!("\"{kind}\"")));
    }
    let origin: [f32; 3] = parse_list(path, "origin", field("origin")?, "three comma-separated numbers")?;
    let cell_s = field("cell")?;
    let cell: f32 = cell_s.trim().parse().map_err(|_| bad(path, "cell", cell_s, "a number"))?;
    let dims: [usize; 3] = parse_list(path, "dims", field("dims")?, "three comma-separated node counts nx,ny,nz")?;
    let geometry_error = |expected: String| CollisionError::BadField {
        path: p(),
        field: "dims/origin/cell",
        found: format!("origin {origin:?}, cell {cell}, dims {dims:?}"),
        expected,
    };
    let geometry = GridGeometry::new(Point3::from(origin), cell, dims).map_err(|e| geometry_error(e.to_string()))?;
    // Each value may be finite while the far corner or the diagonal is not (cell 3e38 or 2e19
    // over 4 nodes): queries would meet infinite coordinates, distances an infinite default.
    if !geometry.diagonal().is_finite() {
        return Err(geometry_error("a grid whose far corner origin + cell·(dims − 1) and diagonal are finite".into()));
    }
    let view = st.tensor(kind).map_err(|_| CollisionError::MissingTensor {
        path: p(),
        name: kind,
        found: st.names().join(", "),
    })?;
    let [nx, ny, nz] = dims;
    if view.dtype() != dtype {
        return Err(CollisionError::BadTensor {
            path: p(),
            name: kind,
            problem: format!("dtype {:?}, expected {dtype:?}", view.dtype()),
        });
    }
    if view.shape() != [nz, ny, nx] {
        return Err(CollisionError::BadTensor {
            path: p(),
            name: kind,
            problem: format!("shape {:?}, expected [nz, ny, nx] = {:?} from metadata dims", view.shape(), [nz, ny, nx]),
        });
    }
    Ok((geometry, view.data().to_vec()))
}

fn f32_from_bytes(bytes: &[u8]) -> Vec<f32> {
    bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
}

/// Write `data` (x-fastest over `geometry`) as a NumPy v1.0 `.npy` array `<f4`, shape
/// `(nz, ny, nx)`, atomically.
fn write_npy(path: &Path, geometry: &GridGeometry, data: &[f32]) -> Result<(), CollisionError> {
    let [nx, ny, nz] = geometry.dims;
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({nz}, {ny}, {nx}), }}");
    // Magic (6) + version (2) + length (2) + header, padded with spaces to a multiple of 64,
    // ending in '\n'.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
    header.push('\n');
    let bytes = f32_bytes(data);
    write_atomically(path, |w| {
        w.write_all(b"\x93NUMPY\x01\x00")?;
        w.write_all(&(header.len() as u16).to_le_bytes())?;
        w.write_all(header.as_bytes())?;
        w.write_all(&bytes)
    })
}

impl ScalarGrid {
    /// Save as safetensors (tensor `"field"`, F32 `[nz, ny, nx]`; see the [module docs](self)).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), CollisionError> {
        save_grid(path.as_ref(), "field", &self.geometry, Dtype::F32, &f32_bytes(&self.data))
    }

    /// Load a file written by [`ScalarGrid::save`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self, CollisionError> {
        let (geometry, bytes) = load_grid(path.as_ref(), "field", Dtype::F32)?;
        Ok(Self { geometry, data: f32_from_bytes(&bytes) })
    }

    /// Export as `.npy` (`<f4`, shape `(nz, ny, nx)`).
    pub fn write_npy(&self, path: impl AsRef<Path>) -> Result<(), CollisionError> {
        write_npy(path.as_ref(), &self.geometry, &self.data)
    }
}

impl SdfGrid {
    /// Save as safetensors (tensor `"sdf"`, F32 metres `[nz, ny, nx]`; see the
    /// [module docs](self)).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), CollisionError> {
        save_grid(path.as_ref(), "sdf", &self.geometry, Dtype::F32, &f32_bytes(&self.data))
    }

    /// Load a file written by [`SdfGrid::save`]; a NaN or infinite distance is an error.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, CollisionError> {
        let path = path.as_ref();
        let (geometry, bytes) = load_grid(path, "sdf", Dtype::F32)?;
        let data = f32_from_bytes(&bytes);
        // Every query interpolates these: one NaN would silently poison a whole cell's answers.
        if let Some(pos) = data.iter().position(|v| !v.is_finite()) {
            return Err(CollisionError::BadTensor {
                path: path.to_path_buf(),
                name: "sdf",
                problem: format!("value {} at flat index {pos}, expected a finite distance in metres", data[pos]),
            });
        }
        Ok(Self { geometry, data })
    }

    /// Export as `.npy` (`<f4` metres, shape `(nz, ny, nx)`); the geometry is not stored, so
    /// keep the safetensors file or the summary alongside.
    pub fn write_npy(&self, path: impl AsRef<Path>) -> Result<(), CollisionError> {
        write_npy(path.as_ref(), &self.geometry, &self.data)
    }
}

impl OccupancyGrid {
    /// Save as safetensors (tensor `"occupancy"`, U8 0/1 `[nz, ny, nx]`).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), CollisionError> {
        let bytes: Vec<u8> = self.data.iter().map(|&o| o as u8).collect();
        save_grid(path.as_ref(), "occupancy", &self.geometry, Dtype::U8, &bytes)
    }

    /// Load a file written by [`OccupancyGrid::save`]; any byte other than 0 or 1 is an error.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, CollisionError> {
        let path = path.as_ref();
        let (geometry, bytes) = load_grid(path, "occupancy", Dtype::U8)?;
        if let Some(pos) = bytes.iter().position(|&b| b > 1) {
            return Err(CollisionError::BadTensor {
                path: path.to_path_buf(),
                name: "occupancy",
                problem: format!("value {} at flat index {pos}, expected 0 or 1", bytes[pos]),
            });
        }
        Ok(Self { geometry, data: bytes.into_iter().map(|b| b == 1).collect() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerfsv_scene::Aabb;

    fn sample_sdf() -> SdfGrid {
        let f = |p: Point3<f32>| (p - Point3::new(0.1, 0.0, 0.2)).norm() - 0.2;
        let grid = ScalarGrid::sample(&Aabb::new(Point3::new(-0.33, -0.3, 0.0), Point3::new(0.4, 0.3, 0.51)), 40.0, f);
        SdfGrid::from_field(&grid, 0.0, true)
    }

    #[test]
    fn grids_round_trip_bit_identically_through_safetensors() {
        let dir = tempfile::tempdir().unwrap();
        let sdf = sample_sdf();
        sdf.save(dir.path().join("sdf.safetensors")).unwrap();
        let back = SdfGrid::load(dir.path().join("sdf.safetensors")).unwrap();
        assert_eq!(back.geometry, sdf.geometry);
        assert!(back.data.iter().zip(&sdf.data).all(|(a, b)| a.to_bits() == b.to_bits()));

        let field = ScalarGrid { geometry: sdf.geometry, data: sdf.data.clone() };
        field.save(dir.path().join("f.safetensors")).unwrap();
        assert_eq!(ScalarGrid::load(dir.path().join("f.safetensors")).unwrap(), field);

        let occ = OccupancyGrid::from_sdf(&sdf);
        occ.save(dir.path().join("o.safetensors")).unwrap();
        assert_eq!(OccupancyGrid::load(dir.path().join("o.safetensors")).unwrap(), occ);
        // Only the three files: no temporaries left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3);
    }

    #[test]
    fn tensor_is_laid_out_z_y_x_for_numpy() {
        let dir = tempfile::tempdir().unwrap();
        let sdf = sample_sdf();
        let path = dir.path().join("sdf.safetensors");
        sdf.save(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let st = SafeTensors::deserialize(&bytes).unwrap();
        let t = st.tensor("sdf").unwrap();
        let [nx, ny, nz] = sdf.dims();
        assert_eq!(t.shape(), [nz, ny, nx]);
        let (x, y, z) = (5, 7, 3);
        let o = 4 * ((z * ny + y) * nx + x);
        assert_eq!(f32::from_le_bytes(t.data()[o..o + 4].try_into().unwrap()), sdf.get(x, y, z));
    }

    fn write_with_metadata(path: &Path, drop: &str, replace: Option<(&str, &str)>) {
        let sdf = sample_sdf();
        sdf.save(path).unwrap();
        let bytes = std::fs::read(path).unwrap();
        let (_, header) = SafeTensors::read_metadata(&bytes).unwrap();
        let mut meta = header.metadata().clone().unwrap();
        meta.remove(drop);
        if let Some((k, v)) = replace {
            meta.insert(k.to_string(), v.to_string());
        }
        let data = f32_bytes(&sdf.data);
        let [nx, ny, nz] = sdf.dims();
        let view = safetensors::tensor::TensorView::new(Dtype::F32, vec![nz, ny, nx], &data).unwrap();
        std::fs::write(path, safetensors::serialize([("sdf", view)], Some(meta)).unwrap()).unwrap();
    }

    #[test]
    fn loading_a_file_without_a_metadata_field_names_the_file_and_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grid.safetensors");
        write_with_metadata(&path, "cell", None);
        let err = SdfGrid::load(&path).unwrap_err();
        assert!(matches!(err, CollisionError::MissingField { field: "cell", .. }), "{err:?}");
        let msg = err.to_string();
        assert!(msg.ends_with("grid.safetensors: metadata field \"cell\" missing"), "{msg}");
    }

    #[test]
    fn loading_rejects_bad_metadata_wrong_kind_and_wrong_shape() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grid.safetensors");
        write_with_metadata(&path, "", Some(("dims", "3,x,4")));
        let msg = SdfGrid::load(&path).unwrap_err().to_string();
        assert!(msg.contains("metadata field \"dims\" is \"3,x,4\""), "{msg}");

        let [nx, ny, nz] = sample_sdf().dims();
        write_with_metadata(&path, "", Some(("dims", &format!("{},{ny},{nz}", nx + 1))));
        let msg = SdfGrid::load(&path).unwrap_err().to_string();
        assert!(msg.contains("tensor \"sdf\": shape"), "{msg}");

        sample_sdf().save(&path).unwrap();
        let msg = ScalarGrid::load(&path).unwrap_err().to_string();
        assert!(msg.contains("metadata field \"kind\" is \"sdf\", expected \"field\""), "{msg}");

        let missing = dir.path().join("nope.safetensors");
        let msg = SdfGrid::load(&missing).unwrap_err().to_string();
        assert!(msg.contains("nope.safetensors"), "{msg}");
    }

    #[test]
    fn loading_refuses_a_geometry_whose_far_corner_or_diagonal_is_infinite() {
        // Found by the property tests (tests/fuzz.rs): each value is finite, the grid is not.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grid.safetensors");
        for cell in ["3e38", "18446744073709551615"] {
            write_with_metadata(&path, "", Some(("cell", cell)));
            let msg = SdfGrid::load(&path).unwrap_err().to_string();
            assert!(msg.contains("grid.safetensors: metadata field \"dims/origin/cell\""), "{msg}");
            assert!(msg.contains("diagonal are finite"), "{msg}");
        }
        write_with_metadata(&path, "", Some(("dims", "100000,100000,100000")));
        let msg = SdfGrid::load(&path).unwrap_err().to_string();
        assert!(msg.contains("grid.safetensors") && msg.contains("fewer than 2^32 - 1 nodes"), "{msg}");
    }

    #[test]
    fn loading_an_sdf_refuses_a_non_finite_distance_naming_its_index() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sdf.safetensors");
        let mut sdf = sample_sdf();
        sdf.data[7] = f32::NAN;
        sdf.save(&path).unwrap();
        let msg = SdfGrid::load(&path).unwrap_err().to_string();
        assert!(msg.contains("sdf.safetensors: tensor \"sdf\": value NaN at flat index 7"), "{msg}");
        // A field may hold any float (a density can overflow): it loads.
        let field = ScalarGrid { geometry: sdf.geometry, data: sdf.data.clone() };
        field.save(&path).unwrap();
        assert!(ScalarGrid::load(&path).unwrap().data[7].is_nan());
    }

    #[test]
    fn npy_export_has_a_valid_v1_header_and_the_data() {
        let dir = tempfile::tempdir().unwrap();
        let sdf = sample_sdf();
        let path = dir.path().join("sdf.npy");
        sdf.write_npy(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        let header = std::str::from_utf8(&bytes[10..10 + hlen]).unwrap();
        let [nx, ny, nz] = sdf.dims();
        assert!(header.contains(&format!("'shape': ({nz}, {ny}, {nx})")), "{header}");
        assert!(header.contains("'descr': '<f4'") && header.ends_with('\n'));
        assert_eq!(f32_from_bytes(&bytes[10 + hlen..]), sdf.data);
    }
}
