//! Reading meshes: OBJ with its MTL (diffuse colour `Kd`, diffuse texture `map_Kd` when it is a
//! PNG), PLY (ascii or binary; vertex colours `red/green/blue` as bytes or floats), glTF 2.0
//! (`.gltf` with external `.bin` buffers, or `.glb`: every mesh of the default scene placed by
//! its node transforms, material base colour, `COLOR_0`). Every error names the file.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Matrix4, Point3, Vector3};

use super::triangle::{MeshError, TriangleMesh, DEFAULT_COLOUR};
use crate::image::Image;

/// Which axis of the file points up, signed: the file is turned by the proper rotation
/// ([`UpAxis::rotation`], determinant +1) taking that axis to +z. Each is a quarter or half turn
/// about a horizontal axis of the file, so the axes other than the up axis stay horizontal.
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[derive(nerfsv_derive::Choice, Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// The file is x-up: `(x, y, z)` becomes `(−z, y, x)`, a quarter turn about y.
    X,
    /// The file is y-up (glTF's convention, Blender's glTF and OBJ exports): `(x, y, z)` becomes
    /// `(x, −z, y)`, a right-handed turn about x.
    Y,
    /// The file is z-up already (nerfsv's frame).
    #[default]
    Z,
    /// The file is −x-up: `(x, y, z)` becomes `(z, y, −x)`, a quarter turn about y.
    #[serde(rename = "-x")]
    #[cfg_attr(feature = "clap", value(name = "-x"))]
    NegX,
    /// The file is −y-up (COLMAP's and OpenCV's y-down worlds): `(x, y, z)` becomes `(x, z, −y)`,
    /// a quarter turn about x.
    #[serde(rename = "-y")]
    #[cfg_attr(feature = "clap", value(name = "-y"))]
    NegY,
    /// The file is −z-up: `(x, y, z)` becomes `(x, −y, −z)`, a half turn about x.
    #[serde(rename = "-z")]
    #[cfg_attr(feature = "clap", value(name = "-z"))]
    NegZ,
}

impl UpAxis {
    /// The file's up axis as a unit vector of the file.
    pub fn vector(self) -> Vector3<f32> {
        match self {
            UpAxis::X => Vector3::x(),
            UpAxis::Y => Vector3::y(),
            UpAxis::Z => Vector3::z(),
            UpAxis::NegX => -Vector3::x(),
            UpAxis::NegY => -Vector3::y(),
            UpAxis::NegZ => -Vector3::z(),
        }
    }

    /// The rotation turning the file's up axis to +z (determinant +1; variant docs).
    pub fn rotation(self) -> Matrix3<f32> {
        match self {
            UpAxis::X => Matrix3::new(0.0, 0.0, -1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0),
            UpAxis::Y => Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0),
            UpAxis::Z => Matrix3::identity(),
            UpAxis::NegX => Matrix3::new(0.0, 0.0, 1.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0),
            UpAxis::NegY => Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0),
            UpAxis::NegZ => Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0),
        }
    }

    /// A point of the file turned z-up: [`UpAxis::rotation`] times `p`, computed exactly (its
    /// coordinates moved and negated, not multiplied).
    pub fn turn(self, p: Point3<f32>) -> Point3<f32> {
        match self {
            UpAxis::X => Point3::new(-p.z, p.y, p.x),
            UpAxis::Y => Point3::new(p.x, -p.z, p.y),
            UpAxis::Z => p,
            UpAxis::NegX => Point3::new(p.z, p.y, -p.x),
            UpAxis::NegY => Point3::new(p.x, p.z, -p.y),
            UpAxis::NegZ => Point3::new(p.x, -p.y, -p.z),
        }
    }
}

/// How a file's coordinates become metres, z up.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MeshOptions {
    /// Metres per file unit.
    pub scale: f32,
    pub up: UpAxis,
}

impl Default for MeshOptions {
    fn default() -> Self {
        Self { scale: 1.0, up: UpAxis::Z }
    }
}

/// A mesh read from a file, with what the reader noticed.
#[derive(Clone, Debug)]
pub struct LoadedMesh {
    pub mesh: TriangleMesh,
    /// Things a user should know (a texture that could not be read, an unsupported primitive),
    /// each naming the file.
    pub warnings: Vec<String>,
}

/// Errors of [`load_mesh`].
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error("{}: {message}", .path.display())]
    Read { path: PathBuf, message: String },
    #[error("{}: {error}", .path.display())]
    Invalid { path: PathBuf, error: MeshError },
}

fn read_error(path: &Path, message: impl std::fmt::Display) -> LoadError {
    LoadError::Read { path: path.to_path_buf(), message: message.to_string() }
}

/// Reads `path` by its extension (`.obj`, `.ply`, `.gltf`, `.glb`), applies `options` and checks
/// the result ([`TriangleMesh::validate`]).
pub fn load_mesh(path: &Path, options: MeshOptions) -> Result<LoadedMesh, LoadError> {
    if !(options.scale.is_finite() && options.scale > 0.0) {
        return Err(read_error(path, format!("scale must be a positive number, found {}", options.scale)));
    }
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).unwrap_or_default();
    // One wording for a file that is not there or not a file, whichever reader would open it.
    match std::fs::metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(read_error(path, "no such file or folder; give the path of an OBJ, PLY, glTF or GLB file"));
        }
        Err(e) => return Err(read_error(path, format!("cannot be read ({e})"))),
        Ok(m) if m.is_dir() => {
            return Err(read_error(
                path,
                "is a folder, not a mesh file; give the path of an OBJ, PLY, glTF or GLB file",
            ));
        }
        Ok(_) => {}
    }
    let not_a = |format: &str, e: &dyn std::fmt::Display| {
        read_error(path, format!("is not a readable {format} file ({e}); export the mesh again or check its extension"))
    };
    let mut loaded = match ext.as_str() {
        "obj" => load_obj(path)?,
        "ply" => load_ply(path)?,
        "gltf" | "glb" => load_gltf(path).map_err(|e| match e {
            LoadError::Read { message, .. } => not_a("glTF 2.0", &message),
            e => e,
        })?,
        _ => return Err(read_error(path, "unknown mesh format: expected .obj, .ply, .gltf or .glb")),
    };
    for p in &mut loaded.mesh.positions {
        *p = options.up.turn(*p) * options.scale;
    }
    loaded.mesh.validate().map_err(|error| LoadError::Invalid { path: path.to_path_buf(), error })?;
    Ok(loaded)
}

fn load_obj(path: &Path) -> Result<LoadedMesh, LoadError> {
    let opts = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let (models, materials) = tobj::load_obj(path, &opts).map_err(|e| read_error(path, e))?;
    let mut warnings = Vec::new();
    let materials = materials.unwrap_or_else(|e| {
        warnings.push(format!("{}: its materials could not be read ({e}); the mesh is grey", path.display()));
        Vec::new()
    });
    // Diffuse textures, read once each; a missing or unreadable one falls back to `Kd`.
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut textures = Vec::new();
    let texture_of: Vec<Option<u32>> = materials
        .iter()
        .map(|m| {
            let name = m.diffuse_texture.as_ref()?;
            let file = dir.join(name);
            match Image::read_png(&file) {
                Ok(img) => {
                    textures.push(img);
                    Some(textures.len() as u32 - 1)
                }
                Err(e) => {
                    warnings.push(format!(
                        "{}: material {:?}: its texture {} could not be read ({e}); using its diffuse colour",
                        path.display(),
                        m.name,
                        file.display()
                    ));
                    None
                }
            }
        })
        .collect();
    let mut mesh = TriangleMesh::default();
    let mut any_uv = false;
    let mut uvs = Vec::new();
    for model in &models {
        let m = &model.mesh;
        let base = mesh.positions.len() as u32;
        let n = m.positions.len() / 3;
        mesh.positions.extend(m.positions.chunks_exact(3).map(|p| Point3::new(p[0], p[1], p[2])));
        if m.texcoords.len() == 2 * n {
            any_uv = true;
            uvs.extend(m.texcoords.chunks_exact(2).map(|t| [t[0], t[1]]));
        } else {
            uvs.extend(std::iter::repeat_n([0.0, 0.0], n));
        }
        let (colour, texture) = match m.material_id.and_then(|i| materials.get(i).map(|mat| (i, mat))) {
            Some((i, mat)) => (mat.diffuse.unwrap_or(DEFAULT_COLOUR), texture_of[i]),
            None => (DEFAULT_COLOUR, None),
        };
        for t in m.indices.chunks_exact(3) {
            mesh.triangles.push([base + t[0], base + t[1], base + t[2]]);
            mesh.face_colours.push(colour);
            mesh.face_textures.push(texture.filter(|_| m.texcoords.len() == 2 * n));
        }
    }
    if any_uv {
        mesh.uvs = Some(uvs);
    }
    mesh.textures = textures;
    Ok(LoadedMesh { mesh, warnings })
}

fn load_ply(path: &Path) -> Result<LoadedMesh, LoadError> {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Property};
    let file = std::fs::File::open(path).map_err(|e| read_error(path, e))?;
    let mut reader = std::io::BufReader::new(file);
    let ply = Parser::<DefaultElement>::new().read_ply(&mut reader).map_err(|e| read_error(path, e))?;
    let scalar = |p: &Property| -> Option<f32> {
        Some(match *p {
            Property::Char(v) => v as f32,
            Property::UChar(v) => v as f32,
            Property::Short(v) => v as f32,
            Property::UShort(v) => v as f32,
            Property::Int(v) => v as f32,
            Property::UInt(v) => v as f32,
            Property::Float(v) => v,
            Property::Double(v) => v as f32,
            _ => return None,
        })
    };
    let vertices = ply.payload.get("vertex").ok_or_else(|| read_error(path, "no `vertex` element"))?;
    let mut mesh = TriangleMesh::default();
    let mut colours = Vec::with_capacity(vertices.len());
    let mut has_colour = true;
    for (i, v) in vertices.iter().enumerate() {
        let get = |k: &str| v.get(k).and_then(scalar);
        let (Some(x), Some(y), Some(z)) = (get("x"), get("y"), get("z")) else {
            return Err(read_error(path, format!("vertex {i} has no numeric x, y, z")));
        };
        mesh.positions.push(Point3::new(x, y, z));
        let channel = |k: &str| {
            v.get(k).map(|p| match p {
                Property::Float(_) | Property::Double(_) => scalar(p).unwrap_or(0.0),
                _ => scalar(p).unwrap_or(0.0) / 255.0,
            })
        };
        match (channel("red"), channel("green"), channel("blue")) {
            (Some(r), Some(g), Some(b)) => colours.push([r, g, b]),
            _ => has_colour = false,
        }
    }
    let faces = ply.payload.get("face").map(Vec::as_slice).unwrap_or(&[]);
    for (i, f) in faces.iter().enumerate() {
        let list: Vec<i64> = match f.get("vertex_indices").or_else(|| f.get("vertex_index")) {
            Some(Property::ListInt(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListUInt(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListShort(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListUShort(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListChar(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListUChar(v)) => v.iter().map(|&x| x as i64).collect(),
            _ => return Err(read_error(path, format!("face {i} has no integer list vertex_indices"))),
        };
        if let Some(&bad) = list.iter().find(|&&x| x < 0 || x > u32::MAX as i64) {
            return Err(read_error(path, format!("face {i} names vertex {bad}")));
        }
        // A polygon becomes a fan.
        for k in 2..list.len() {
            mesh.triangles.push([list[0] as u32, list[k - 1] as u32, list[k] as u32]);
        }
    }
    let n = mesh.triangles.len();
    mesh.face_colours = vec![DEFAULT_COLOUR; n];
    mesh.face_textures = vec![None; n];
    if has_colour && !colours.is_empty() {
        mesh.vertex_colours = Some(colours);
    }
    Ok(LoadedMesh { mesh, warnings: Vec::new() })
}

fn load_gltf(path: &Path) -> Result<LoadedMesh, LoadError> {
    let bytes = std::fs::read(path).map_err(|e| read_error(path, e))?;
    let gltf = gltf::Gltf::from_slice(&bytes).map_err(|e| read_error(path, e))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut buffers = Vec::new();
    for b in gltf.buffers() {
        let data = match b.source() {
            gltf::buffer::Source::Bin => gltf
                .blob
                .clone()
                .ok_or_else(|| read_error(path, format!("buffer {} refers to a missing GLB chunk", b.index())))?,
            gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                return Err(read_error(
                    path,
                    format!("buffer {} is an embedded data URI: export as .glb or with a separate .bin", b.index()),
                ))
            }
            gltf::buffer::Source::Uri(uri) => {
                let file = dir.join(uri);
                std::fs::read(&file)
                    .map_err(|e| read_error(path, format!("buffer {}: {}: {e}", b.index(), file.display())))?
            }
        };
        buffers.push(data);
    }
    let mut mesh = TriangleMesh::default();
    let mut colours: Vec<[f32; 3]> = Vec::new();
    let mut any_colour = false;
    let mut warnings = Vec::new();
    let scene = gltf.default_scene().or_else(|| gltf.scenes().next()).ok_or_else(|| read_error(path, "no scene"))?;
    let mut stack: Vec<(gltf::Node, Matrix4<f32>)> = scene.nodes().map(|n| (n, Matrix4::identity())).collect();
    while let Some((node, parent)) = stack.pop() {
        let local = Matrix4::from(node.transform().matrix());
        let world = parent * local;
        for child in node.children() {
            stack.push((child, world));
        }
        let Some(m) = node.mesh() else { continue };
        for prim in m.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                warnings.push(format!(
                    "{}: mesh {} has a primitive of mode {:?}, skipped",
                    path.display(),
                    m.index(),
                    prim.mode()
                ));
                continue;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
            let Some(positions) = reader.read_positions() else { continue };
            let base = mesh.positions.len() as u32;
            mesh.positions.extend(positions.map(|p| world.transform_point(&Point3::from(p))));
            let n = mesh.positions.len() - base as usize;
            match reader.read_colors(0) {
                Some(c) => {
                    any_colour = true;
                    colours.extend(c.into_rgb_f32());
                }
                None => colours.extend(std::iter::repeat_n(DEFAULT_COLOUR, n)),
            }
            let base_colour = prim.material().pbr_metallic_roughness().base_color_factor();
            let colour = [base_colour[0], base_colour[1], base_colour[2]];
            if prim.material().pbr_metallic_roughness().base_color_texture().is_some() {
                warnings.push(format!(
                    "{}: mesh {}: base colour textures are not read; using the base colour factor",
                    path.display(),
                    m.index()
                ));
            }
            let indices: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..n as u32).collect(),
            };
            for t in indices.chunks_exact(3) {
                mesh.triangles.push([base + t[0], base + t[1], base + t[2]]);
                mesh.face_colours.push(colour);
                mesh.face_textures.push(None);
            }
        }
    }
    if any_colour {
        mesh.vertex_colours = Some(colours);
    }
    warnings.dedup();
    Ok(LoadedMesh { mesh, warnings })
}

/// Writes `mesh` as a binary little-endian PLY with its vertex colours (bytes), or without
/// colours when it has none.
pub fn ply_bytes(mesh: &TriangleMesh) -> Vec<u8> {
    let colours = mesh.vertex_colours.as_ref();
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
        mesh.positions.len()
    );
    if colours.is_some() {
        header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    header.push_str(&format!(
        "element face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        mesh.triangles.len()
    ));
    let mut out = header.into_bytes();
    for (i, p) in mesh.positions.iter().enumerate() {
        for v in [p.x, p.y, p.z] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        if let Some(c) = colours {
            out.extend(c[i].map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8));
        }
    }
    for t in &mesh.triangles {
        out.push(3);
        for i in t {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::super::tests::cube;
    use super::*;

    #[test]
    fn a_ply_round_trips_with_its_colours_and_a_y_up_file_turns_to_z_up() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = cube(0.0, 1.0, false);
        c.vertex_colours = Some((0..8).map(|i| [i as f32 / 7.0, 0.5, 1.0 - i as f32 / 7.0]).collect());
        let path = dir.path().join("c.ply");
        std::fs::write(&path, ply_bytes(&c)).unwrap();
        let back = load_mesh(&path, MeshOptions::default()).unwrap().mesh;
        assert_eq!(back.positions, c.positions);
        assert_eq!(back.triangles, c.triangles);
        let (a, b) = (back.vertex_colours.unwrap(), c.vertex_colours.unwrap());
        for (x, y) in a.iter().zip(&b) {
            for k in 0..3 {
                assert!((x[k] - y[k]).abs() <= 0.5 / 255.0 + 1e-6);
            }
        }
        let y_up = load_mesh(&path, MeshOptions { scale: 2.0, up: UpAxis::Y }).unwrap().mesh;
        // (x, y, z) → 2·(x, −z, y)
        assert_eq!(y_up.positions[4], Point3::new(0.0, -2.0, 0.0)); // vertex (0, 0, 1)
        assert_eq!(y_up.positions[2], Point3::new(0.0, 0.0, 2.0)); // vertex (0, 1, 0)
    }

    #[test]
    fn every_up_axis_turns_to_z_by_a_proper_rotation() {
        let names: Vec<&str> = UpAxis::ALL.iter().map(|u| u.name()).collect();
        assert_eq!(names, ["x", "y", "z", "-x", "-y", "-z"]);
        let p = Point3::new(1.5, -2.25, 3.0);
        for up in UpAxis::ALL {
            let r = up.rotation();
            assert_eq!(r.determinant(), 1.0, "{up}");
            assert_eq!(r * r.transpose(), Matrix3::identity(), "{up}");
            assert_eq!(r * up.vector(), Vector3::z(), "{up}");
            assert_eq!(up.turn(p), Point3::from(r * p.coords), "{up}");
            assert_eq!(up.name().parse::<UpAxis>(), Ok(up));
            assert_eq!(serde_json::to_string(&up).unwrap(), format!("{:?}", up.name()));
        }
        // z and y as they always were.
        assert_eq!(UpAxis::Z.rotation(), Matrix3::identity());
        assert_eq!(UpAxis::Y.turn(p), Point3::new(1.5, -3.0, -2.25));
        assert_eq!("w".parse::<UpAxis>().unwrap_err(), "unknown up axis \"w\": one of x, y, z, -x, -y, -z");
    }

    #[test]
    fn bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, text: &str| {
            let p = dir.path().join(name);
            std::fs::write(&p, text).unwrap();
            p
        };
        let e = load_mesh(&write("empty.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"), MeshOptions::default()).unwrap_err();
        assert!(e.to_string().contains("empty.obj") && e.to_string().contains("no triangles"), "{e}");
        let e = load_mesh(&write("nan.obj", "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n"), MeshOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("nan.obj"), "{e}");
        let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                   element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
        let e = load_mesh(&write("range.ply", ply), MeshOptions::default()).unwrap_err().to_string();
        assert!(e.contains("range.ply") && e.contains("vertex 7"), "{e}");
        let e = load_mesh(&write("m.stl", "solid"), MeshOptions::default()).unwrap_err().to_string();
        assert!(e.contains("unknown mesh format"), "{e}");
        let e = load_mesh(&dir.path().join("gone.ply"), MeshOptions::default()).unwrap_err().to_string();
        assert!(e.contains("gone.ply"), "{e}");
    }

    #[test]
    fn an_obj_with_a_missing_texture_warns_and_uses_its_diffuse_colour() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("m.mtl"), "newmtl red\nKd 0.8 0.1 0.1\nmap_Kd gone.png\n").unwrap();
        std::fs::write(
            dir.path().join("m.obj"),
            "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl red\nf 1/1 2/2 3/3\n",
        )
        .unwrap();
        let loaded = load_mesh(&dir.path().join("m.obj"), MeshOptions::default()).unwrap();
        assert_eq!(loaded.warnings.len(), 1, "{:?}", loaded.warnings);
        assert!(loaded.warnings[0].contains("gone.png"));
        assert_eq!(loaded.mesh.colour_at(0, 0.2, 0.2), [0.8, 0.1, 0.1]);
    }
}
