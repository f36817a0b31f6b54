//! A scene of triangle meshes and polylines as binary glTF 2.0 (`.glb`), written by hand: what
//! `nerfsv export` writes for Blender or any glTF viewer.
//!
//! Plain data in, bytes out ([`glb_bytes`]); the caller writes the file (atomically). Each
//! [`GlbNode`] becomes one glTF node holding one mesh of one primitive: a triangle mesh
//! (`TRIANGLES`, indexed with `u32`) or a polyline (`LINE_STRIP`, its points in order), with one
//! of the scene's [`GlbMaterial`]s (a base colour; an alpha below 1 blends). Nodes that name a
//! group are the children of one empty node of that name, so a viewer's outliner shows them
//! folded together.
//!
//! # Coordinates
//! Positions are given in nerfsv's world frame: metres, z up, right-handed. glTF is metres, y up,
//! right-handed, so each point `(x, y, z)` is written as `(x, z, −y)` ([`to_gltf_axes`]), a turn
//! of −90° about x: the ground plane z = 0 becomes glTF's y = 0 and the world's +y points to
//! glTF's −z (into the screen of a viewer's default front view). Blender's glTF importer turns
//! it back, so a point reads with the same coordinates in Blender as in nerfsv.
//!
//! # Layout
//! A 12-byte header (`glTF`, version 2, total length), the JSON chunk padded with spaces to a
//! multiple of 4 bytes, then the BIN chunk padded with zeros (absent when there is no geometry).
//! Each primitive's positions (`f32` VEC3, with their `min`/`max`) and indices (`u32`) are a
//! buffer view of their own (targets 34962 and 34963). `asset.generator` starts with `nerfsv`,
//! which is how nerfsv recognises a file it may replace.

use serde_json::{json, Value};

/// `asset.generator` of every file written here (nerfsv recognises its own files by the prefix
/// `nerfsv`).
pub const GENERATOR: &str = concat!("nerfsv ", env!("CARGO_PKG_VERSION"));

/// glTF's primitive modes used here.
pub const MODE_LINE_STRIP: u32 = 3;
pub const MODE_TRIANGLES: u32 = 4;

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// A material: a name and a base colour (linear RGB and alpha in `[0, 1]`; alpha below 1 is
/// drawn blended). Metallic 0, roughness 1, double-sided.
#[derive(Clone, Debug, PartialEq)]
pub struct GlbMaterial {
    pub name: String,
    pub rgba: [f32; 4],
}

/// What a node draws, in nerfsv's frame (metres, z up).
#[derive(Clone, Debug, PartialEq)]
pub enum GlbShape {
    /// A triangle mesh: vertex positions and the vertex indices of each triangle.
    Triangles { positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]> },
    /// A polyline through its points in order (at least two).
    LineStrip { points: Vec<[f32; 3]> },
}

/// One named node of the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct GlbNode {
    /// The node's (and its mesh's) name, as a viewer's outliner shows it.
    pub name: String,
    /// The group node it sits under (`None`: at the scene's top level).
    pub group: Option<String>,
    /// Index into [`GlbScene::materials`].
    pub material: usize,
    pub shape: GlbShape,
}

/// Everything one file holds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GlbScene {
    pub materials: Vec<GlbMaterial>,
    pub nodes: Vec<GlbNode>,
}

/// Why a scene cannot be written; each names the node.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GlbError {
    #[error("node {node:?}: a triangle mesh needs at least one triangle")]
    NoTriangles { node: String },
    #[error("node {node:?}: a polyline needs at least two points, found {points}")]
    ShortLine { node: String, points: usize },
    #[error("node {node:?}: point {index} has a non-finite coordinate")]
    NonFinite { node: String, index: usize },
    #[error("node {node:?}: triangle {triangle} names vertex {index}, but the mesh has {vertices} vertices")]
    IndexOutOfRange { node: String, triangle: usize, index: u32, vertices: usize },
    #[error("node {node:?}: material {material} does not exist (the scene has {materials})")]
    UnknownMaterial { node: String, material: usize, materials: usize },
    #[error("material {name:?}: colour {rgba:?} is not within [0, 1]")]
    Colour { name: String, rgba: [f32; 4] },
    #[error("the scene needs {bytes} bytes, more than a GLB file holds (4 GiB)")]
    TooLarge { bytes: usize },
}

/// nerfsv's `(x, y, z)` (z up) as glTF's `(x, z, −y)` (y up).
pub fn to_gltf_axes(p: [f32; 3]) -> [f32; 3] {
    [p[0], p[2], -p[1]]
}

/// The binary buffer and the JSON arrays that describe it, filled node by node.
#[derive(Default)]
struct Builder {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Builder {
    /// Appends `bytes` as a buffer view for `target`; its index.
    fn view(&mut self, bytes: &[u8], target: u32) -> usize {
        // Every element here is 4 bytes, so views stay aligned without padding between them.
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.views.push(json!({ "buffer": 0, "byteOffset": offset, "byteLength": bytes.len(), "target": target }));
        self.views.len() - 1
    }

    /// The positions (converted to glTF's axes) as a VEC3 accessor with min and max; its index.
    fn positions(&mut self, points: &[[f32; 3]]) -> usize {
        let converted: Vec<[f32; 3]> = points.iter().copied().map(to_gltf_axes).collect();
        let (mut min, mut max) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in &converted {
            for k in 0..3 {
                min[k] = min[k].min(p[k]);
                max[k] = max[k].max(p[k]);
            }
        }
        let bytes: Vec<u8> = converted.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes, ARRAY_BUFFER);
        self.accessors.push(json!({
            "bufferView": view, "byteOffset": 0, "componentType": FLOAT, "count": converted.len(),
            "type": "VEC3", "min": min, "max": max,
        }));
        self.accessors.len() - 1
    }

    /// The triangles' indices as a SCALAR `u32` accessor; its index.
    fn indices(&mut self, triangles: &[[u32; 3]]) -> usize {
        let bytes: Vec<u8> = triangles.iter().flatten().flat_map(|i| i.to_le_bytes()).collect();
        let view = self.view(&bytes, ELEMENT_ARRAY_BUFFER);
        self.accessors.push(json!({
            "bufferView": view, "byteOffset": 0, "componentType": UNSIGNED_INT, "count": triangles.len() * 3,
            "type": "SCALAR",
        }));
        self.accessors.len() - 1
    }
}

/// Checks a node's shape and material before anything is written.
fn check_node(node: &GlbNode, materials: usize) -> Result<(), GlbError> {
    let name = || node.name.clone();
    if node.material >= materials {
        return Err(GlbError::UnknownMaterial { node: name(), material: node.material, materials });
    }
    let points = match &node.shape {
        GlbShape::Triangles { positions, triangles } => {
            if triangles.is_empty() {
                return Err(GlbError::NoTriangles { node: name() });
            }
            for (t, tri) in triangles.iter().enumerate() {
                if let Some(&index) = tri.iter().find(|&&i| i as usize >= positions.len()) {
                    return Err(GlbError::IndexOutOfRange {
                        node: name(),
                        triangle: t,
                        index,
                        vertices: positions.len(),
                    });
                }
            }
            positions
        }
        GlbShape::LineStrip { points } if points.len() < 2 => {
            return Err(GlbError::ShortLine { node: name(), points: points.len() });
        }
        GlbShape::LineStrip { points } => points,
    };
    match points.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
        Some(index) => Err(GlbError::NonFinite { node: name(), index }),
        None => Ok(()),
    }
}

/// The material's JSON.
fn material_json(m: &GlbMaterial) -> Result<Value, GlbError> {
    if m.rgba.iter().any(|v| !(0.0..=1.0).contains(v)) {
        return Err(GlbError::Colour { name: m.name.clone(), rgba: m.rgba });
    }
    let mut v = json!({
        "name": m.name,
        "pbrMetallicRoughness": { "baseColorFactor": m.rgba, "metallicFactor": 0.0, "roughnessFactor": 1.0 },
        "doubleSided": true,
    });
    if m.rgba[3] < 1.0 {
        v["alphaMode"] = json!("BLEND");
    }
    Ok(v)
}

/// The scene as the JSON document and its binary buffer.
fn document(scene: &GlbScene) -> Result<(Value, Vec<u8>), GlbError> {
    let materials = scene.materials.iter().map(material_json).collect::<Result<Vec<_>, _>>()?;
    let mut b = Builder::default();
    let (mut nodes, mut meshes) = (Vec::new(), Vec::new());
    // Top-level entries in order of first appearance: an ungrouped node, or a group's node
    // (its index among `groups`) with its children.
    let mut roots: Vec<Result<usize, usize>> = Vec::new();
    let mut groups: Vec<(&str, Vec<usize>)> = Vec::new();
    for (i, node) in scene.nodes.iter().enumerate() {
        check_node(node, scene.materials.len())?;
        let primitive = match &node.shape {
            GlbShape::Triangles { positions, triangles } => {
                let position = b.positions(positions);
                let indices = b.indices(triangles);
                json!({ "attributes": { "POSITION": position }, "indices": indices,
                        "mode": MODE_TRIANGLES, "material": node.material })
            }
            GlbShape::LineStrip { points } => {
                let position = b.positions(points);
                json!({ "attributes": { "POSITION": position }, "mode": MODE_LINE_STRIP, "material": node.material })
            }
        };
        meshes.push(json!({ "name": node.name, "primitives": [primitive] }));
        nodes.push(json!({ "name": node.name, "mesh": i }));
        match &node.group {
            None => roots.push(Ok(i)),
            Some(g) => match groups.iter().position(|(name, _)| name == g) {
                Some(k) => groups[k].1.push(i),
                None => {
                    roots.push(Err(groups.len()));
                    groups.push((g, vec![i]));
                }
            },
        }
    }
    let first_group = nodes.len();
    for (name, children) in &groups {
        nodes.push(json!({ "name": name, "children": children }));
    }
    let roots: Vec<usize> = roots.into_iter().map(|r| r.unwrap_or_else(|k| first_group + k)).collect();
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": GENERATOR },
        "scene": 0,
        "scenes": [{ "name": "nerfsv", "nodes": roots }],
        "nodes": nodes,
    });
    if !materials.is_empty() {
        doc["materials"] = Value::Array(materials);
    }
    if !meshes.is_empty() {
        doc["meshes"] = Value::Array(meshes);
        doc["accessors"] = Value::Array(b.accessors);
        doc["bufferViews"] = Value::Array(b.views);
        doc["buffers"] = json!([{ "byteLength": b.bin.len() }]);
    }
    Ok((doc, b.bin))
}

/// Appends a chunk (length, type, data padded with `pad` to a multiple of 4 bytes).
fn push_chunk(out: &mut Vec<u8>, kind: u32, data: &[u8], pad: u8) {
    let padded = data.len().next_multiple_of(4);
    out.extend_from_slice(&(padded as u32).to_le_bytes());
    out.extend_from_slice(&kind.to_le_bytes());
    out.extend_from_slice(data);
    out.resize(out.len() + padded - data.len(), pad);
}

/// The scene as the bytes of a `.glb` file (see the module docs).
pub fn glb_bytes(scene: &GlbScene) -> Result<Vec<u8>, GlbError> {
    let (doc, bin) = document(scene)?;
    let json = doc.to_string().into_bytes();
    let bin_chunk = if bin.is_empty() { 0 } else { 8 + bin.len().next_multiple_of(4) };
    let total = 12 + 8 + json.len().next_multiple_of(4) + bin_chunk;
    if u32::try_from(total).is_err() {
        return Err(GlbError::TooLarge { bytes: total });
    }
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    push_chunk(&mut out, CHUNK_JSON, &json, b' ');
    if !bin.is_empty() {
        push_chunk(&mut out, CHUNK_BIN, &bin, 0);
    }
    debug_assert_eq!(out.len(), total);
    Ok(out)
}

/// The JSON document of a `.glb` file's bytes (`None` if they are not one): what a reader needs to
/// tell who wrote it (`asset.generator`).
pub fn glb_json(bytes: &[u8]) -> Option<Value> {
    if bytes.get(..4)? != MAGIC {
        return None;
    }
    let word = |at: usize| bytes.get(at..at + 4).and_then(|b| b.try_into().ok()).map(u32::from_le_bytes);
    let (len, kind) = (word(12)? as usize, word(16)?);
    if kind != CHUNK_JSON {
        return None;
    }
    serde_json::from_slice(bytes.get(20..20usize.checked_add(len)?)?).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(name: &str, points: Vec<[f32; 3]>) -> GlbNode {
        GlbNode { name: name.into(), group: None, material: 0, shape: GlbShape::LineStrip { points } }
    }

    fn one_material(nodes: Vec<GlbNode>) -> GlbScene {
        GlbScene { materials: vec![GlbMaterial { name: "m".into(), rgba: [1.0, 0.0, 0.0, 1.0] }], nodes }
    }

    #[test]
    fn the_header_and_chunks_are_laid_out_and_padded_as_the_specification_says() {
        let scene = one_material(vec![line("a", vec![[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])]);
        let bytes = glb_bytes(&scene).unwrap();
        assert_eq!(&bytes[..4], b"glTF");
        assert_eq!(u32::from_le_bytes(bytes[4..8].try_into().unwrap()), 2);
        assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize, bytes.len());
        let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        assert_eq!(json_len % 4, 0);
        assert_eq!(&bytes[16..20], b"JSON");
        let json = &bytes[20..20 + json_len];
        let end = json.iter().rposition(|&b| b != b' ').unwrap() + 1;
        assert!(json_len - end < 4, "padded with spaces to 4 bytes only");
        serde_json::from_slice::<Value>(&json[..end]).unwrap();
        let bin_at = 20 + json_len;
        let bin_len = u32::from_le_bytes(bytes[bin_at..bin_at + 4].try_into().unwrap()) as usize;
        assert_eq!(&bytes[bin_at + 4..bin_at + 8], b"BIN\0");
        assert_eq!(bin_len, 24); // two points × 3 × f32
        assert_eq!(bin_at + 8 + bin_len, bytes.len());
        let floats: Vec<f32> =
            bytes[bin_at + 8..].chunks(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
        assert_eq!(floats, [0.0, 0.0, -0.0, 1.0, 3.0, -2.0]);
        let doc = glb_json(&bytes).unwrap();
        assert_eq!(doc["asset"]["version"], "2.0");
        assert!(doc["asset"]["generator"].as_str().unwrap().starts_with("nerfsv"));
        assert_eq!(doc["accessors"][0]["min"], json!([0.0, 0.0, -2.0]));
        assert_eq!(doc["accessors"][0]["max"], json!([1.0, 3.0, 0.0]));
        assert_eq!(doc["bufferViews"][0]["target"], ARRAY_BUFFER);
    }

    #[test]
    fn groups_hold_their_nodes_and_come_in_order_of_first_appearance() {
        let mut a = line("a", vec![[0.0; 3], [1.0; 3]]);
        let b = line("b", vec![[0.0; 3], [1.0; 3]]);
        let mut c = line("c", vec![[0.0; 3], [1.0; 3]]);
        a.group = Some("g".into());
        c.group = Some("g".into());
        let doc = glb_json(&glb_bytes(&one_material(vec![a, b, c])).unwrap()).unwrap();
        assert_eq!(doc["nodes"][3], json!({ "name": "g", "children": [0, 2] }));
        assert_eq!(doc["scenes"][0]["nodes"], json!([3, 1]));
    }

    #[test]
    fn bad_shapes_and_materials_are_refused_by_node_name() {
        let check = |n: GlbNode| glb_bytes(&one_material(vec![n])).unwrap_err();
        assert_eq!(check(line("one", vec![[0.0; 3]])), GlbError::ShortLine { node: "one".into(), points: 1 });
        let e = check(line("nan", vec![[0.0; 3], [f32::NAN, 0.0, 0.0]]));
        assert_eq!(e, GlbError::NonFinite { node: "nan".into(), index: 1 });
        let mut m = line("m", vec![[0.0; 3], [1.0; 3]]);
        m.material = 1;
        assert!(check(m).to_string().contains("node \"m\": material 1 does not exist"));
        let tri = |triangles: Vec<[u32; 3]>| GlbNode {
            name: "t".into(),
            group: None,
            material: 0,
            shape: GlbShape::Triangles { positions: vec![[0.0; 3]; 3], triangles },
        };
        assert_eq!(check(tri(vec![])), GlbError::NoTriangles { node: "t".into() });
        assert!(matches!(check(tri(vec![[0, 1, 3]])), GlbError::IndexOutOfRange { index: 3, .. }));
        let mut s = one_material(vec![]);
        s.materials[0].rgba[0] = 2.0;
        assert!(matches!(glb_bytes(&s), Err(GlbError::Colour { .. })));
    }

    #[test]
    fn an_empty_scene_has_no_binary_chunk_and_other_bytes_are_not_a_glb() {
        let bytes = glb_bytes(&GlbScene::default()).unwrap();
        assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize, bytes.len());
        assert!(glb_json(&bytes).unwrap().get("buffers").is_none());
        assert!(glb_json(b"ply\nformat ascii 1.0\n").is_none());
        assert!(glb_json(&bytes[..15]).is_none());
    }
}
