//! A field's file: saving and loading it (safetensors), and refusing one built from another
//! model.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use nalgebra::Point3;
use nerfsv_collision::GridGeometry;
use safetensors::tensor::Dtype;
use safetensors::SafeTensors;

use super::types::{FieldFigures, FieldMethod, NodeValues, UncertaintyField, FIELD_FORMAT, FIELD_FORMAT_VERSION};
use crate::UqError;

impl UncertaintyField {
    /// Refuses a field built from another model than the one whose [`model_id`](super::model_id) is
    /// `checkpoint_id`: [`UqError::FieldCheckpoint`] naming the field file `path` and both
    /// identifiers.
    pub fn check_checkpoint(&self, path: &Path, checkpoint_id: &str) -> Result<(), UqError> {
        if self.checkpoint_id == checkpoint_id {
            return Ok(());
        }
        Err(UqError::FieldCheckpoint {
            path: path.to_path_buf(),
            field_checkpoint: self.checkpoint_id.clone(),
            built_from: self.checkpoint.clone(),
            checkpoint: checkpoint_id.to_string(),
        })
    }

    /// Writes the field to `path` atomically (see the [module docs](super)).
    pub fn save(&self, path: &Path) -> Result<(), UqError> {
        let [nx, ny, nz] = self.geometry.dims;
        let o = self.geometry.origin;
        let figures = serde_json::to_string(&self.figures).unwrap_or_default();
        let meta: BTreeMap<String, String> = [
            ("format", FIELD_FORMAT.to_string()),
            ("format_version", FIELD_FORMAT_VERSION.to_string()),
            ("method", self.method.name().to_string()),
            ("origin", format!("{},{},{}", o.x, o.y, o.z)),
            ("cell", format!("{}", self.geometry.cell)),
            ("dims", format!("{nx},{ny},{nz}")),
            ("checkpoint_id", self.checkpoint_id.clone()),
            ("checkpoint", self.checkpoint.clone()),
            ("figures", figures),
            ("empty_density", format!("{}", self.empty_density)),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        let bytes = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let (d, v, w) = (bytes(&self.density), bytes(&self.variance), bytes(&self.weight));
        let shape = vec![nz, ny, nx];
        let tensors = [
            nerfsv_scene::io::TensorBytes { name: "density", dtype: "F32", shape: shape.clone(), data: &d },
            nerfsv_scene::io::TensorBytes { name: "variance", dtype: "F32", shape: shape.clone(), data: &v },
            nerfsv_scene::io::TensorBytes { name: "weight", dtype: "F32", shape, data: &w },
        ];
        let buf = nerfsv_scene::io::safetensors_bytes(&tensors, &meta);
        nerfsv_scene::io::atomic_write_bytes(path, &buf)
            .map_err(|error| UqError::FieldIo { path: path.to_path_buf(), error })
    }

    /// Reads a field written by [`save`](Self::save). Errors name the file: unreadable
    /// ([`UqError::FieldIo`]), not a field file, truncated, or a bad value
    /// ([`UqError::FieldFile`]).
    pub fn load(path: &Path) -> Result<Self, UqError> {
        let p = || path.to_path_buf();
        let bad = |message: String| UqError::FieldFile { path: p(), message };
        let buf = std::fs::read(path).map_err(|error| UqError::FieldIo { path: p(), error })?;
        let st = SafeTensors::deserialize(&buf).map_err(|e| bad(format!("not a safetensors file ({e})")))?;
        let (_, header) = SafeTensors::read_metadata(&buf).map_err(|e| bad(format!("not a safetensors file ({e})")))?;
        let empty = HashMap::new();
        let meta = header.metadata().as_ref().unwrap_or(&empty);
        let field = |k: &str| meta.get(k).ok_or_else(|| bad(format!("metadata field {k:?} missing")));
        let format = field("format")?;
        if format != FIELD_FORMAT {
            return Err(bad(format!("format is {format:?}, expected {FIELD_FORMAT:?}")));
        }
        let version = field("format_version")?;
        if version != FIELD_FORMAT_VERSION {
            return Err(bad(format!("format_version is {version:?}, expected {FIELD_FORMAT_VERSION:?}")));
        }
        let method: FieldMethod =
            field("method")?.parse().map_err(|e| bad(format!("metadata field \"method\": {e}")))?;
        fn list<T: std::str::FromStr>(s: &str) -> Option<[T; 3]> {
            let v: Vec<T> = s.split(',').map(|x| x.trim().parse().ok()).collect::<Option<_>>()?;
            v.try_into().ok()
        }
        let origin: [f32; 3] = list(field("origin")?).ok_or_else(|| bad("origin: expected three numbers".into()))?;
        let cell: f32 = field("cell")?.trim().parse().map_err(|_| bad("cell: expected a number".into()))?;
        let dims: [usize; 3] =
            list(field("dims")?).ok_or_else(|| bad("dims: expected three node counts nx,ny,nz".into()))?;
        let geometry =
            GridGeometry::new(Point3::from(origin), cell, dims).map_err(|e| bad(format!("grid geometry: {e}")))?;
        if !geometry.diagonal().is_finite() {
            return Err(bad("grid geometry: the far corner is not finite".into()));
        }
        let figures: FieldFigures =
            serde_json::from_str(field("figures")?).map_err(|e| bad(format!("figures: {e}")))?;
        let [nx, ny, nz] = dims;
        let tensor = |name: &str| -> Result<Vec<f32>, UqError> {
            let t = st.tensor(name).map_err(|_| bad(format!("tensor {name:?} missing")))?;
            if t.dtype() != Dtype::F32 || t.shape() != [nz, ny, nx] {
                return Err(bad(format!(
                    "tensor {name:?} is {:?} {:?}, expected F32 [nz, ny, nx] = {:?}",
                    t.dtype(),
                    t.shape(),
                    [nz, ny, nx]
                )));
            }
            let v: Vec<f32> = t.data().chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(bad(format!("tensor {name:?}: value {} at flat index {i} is not finite", v[i])));
            }
            Ok(v)
        };
        let (density, variance, weight) = (tensor("density")?, tensor("variance")?, tensor("weight")?);
        Self::from_parts(
            method,
            geometry,
            NodeValues { density, variance, weight },
            field("checkpoint_id")?.clone(),
            field("checkpoint")?.clone(),
            figures,
        )
        .map_err(|e| bad(e.to_string()))
        .and_then(|mut f| {
            let e = field("empty_density")?;
            let v: f32 = e.trim().parse().map_err(|_| bad(format!("empty_density is {e:?}, expected a number")))?;
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(format!("empty_density is {v}, expected a finite number ≥ 0")));
            }
            f.set_empty_density(v);
            Ok(f)
        })
    }
}
