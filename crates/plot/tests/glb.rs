//! The GLB writer read back by an independent reader (the `gltf` crate): a triangle mesh and two
//! polylines keep their vertices (turned from z up to y up), indices, modes, materials and names.

use gltf::mesh::Mode;
use nerfsv_plot::glb::{glb_bytes, to_gltf_axes, GlbMaterial, GlbNode, GlbScene, GlbShape};

fn scene() -> GlbScene {
    let materials = vec![
        GlbMaterial { name: "ground".into(), rgba: [0.5, 0.5, 0.5, 1.0] },
        GlbMaterial { name: "track".into(), rgba: [0.9, 0.1, 0.1, 1.0] },
        GlbMaterial { name: "glass".into(), rgba: [0.2, 0.8, 0.3, 0.35] },
    ];
    let tri = GlbShape::Triangles {
        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]],
        triangles: vec![[0, 1, 2], [0, 1, 3]],
    };
    let nodes = vec![
        GlbNode { name: "ground mesh".into(), group: Some("meshes".into()), material: 0, shape: tri },
        GlbNode {
            name: "mc NeRF-sim rollout 0/3 true".into(),
            group: Some("failures".into()),
            material: 1,
            shape: GlbShape::LineStrip { points: vec![[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.7, 0.8, 0.9]] },
        },
        GlbNode {
            name: "route".into(),
            group: None,
            material: 2,
            shape: GlbShape::LineStrip { points: vec![[-1.0, -2.0, 0.5], [3.0, 4.0, 0.25]] },
        },
    ];
    GlbScene { materials, nodes }
}

#[test]
fn a_mesh_and_two_polylines_read_back_through_the_gltf_crate() {
    let written = scene();
    let bytes = glb_bytes(&written).unwrap();
    let glb = gltf::Gltf::from_slice(&bytes).expect("the gltf crate reads the file");
    let blob = glb.blob.as_deref().expect("a BIN chunk");
    let doc = &glb.document;
    assert!(doc.as_json().asset.generator.as_deref().unwrap().starts_with("nerfsv"));
    assert_eq!(doc.as_json().asset.version, "2.0");

    // The scene: the group "meshes" (first seen first), then "failures", then the route.
    let top: Vec<&str> = doc.default_scene().unwrap().nodes().map(|n| n.name().unwrap()).collect();
    assert_eq!(top, ["meshes", "failures", "route"]);
    let meshes = doc.default_scene().unwrap().nodes().next().unwrap();
    assert_eq!(meshes.children().map(|c| c.name().unwrap().to_owned()).collect::<Vec<_>>(), ["ground mesh"]);

    for (node, expected) in doc.nodes().filter(|n| n.mesh().is_some()).zip(&written.nodes) {
        assert_eq!(node.name(), Some(expected.name.as_str()));
        let mesh = node.mesh().unwrap();
        let prims: Vec<_> = mesh.primitives().collect();
        assert_eq!(prims.len(), 1);
        let prim = &prims[0];
        let material = &written.materials[expected.material];
        assert_eq!(prim.material().name(), Some(material.name.as_str()));
        assert_eq!(prim.material().pbr_metallic_roughness().base_color_factor(), material.rgba);
        let blend = prim.material().alpha_mode() == gltf::material::AlphaMode::Blend;
        assert_eq!(blend, material.rgba[3] < 1.0, "{}", material.name);
        let reader = prim.reader(|b| (b.index() == 0).then_some(blob));
        let positions: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
        let bounds = prim.bounding_box();
        for p in &positions {
            for (k, &x) in p.iter().enumerate() {
                assert!(bounds.min[k] <= x && x <= bounds.max[k]);
            }
        }
        match &expected.shape {
            GlbShape::Triangles { positions: given, triangles } => {
                assert_eq!(prim.mode(), Mode::Triangles);
                assert_eq!(positions, given.iter().map(|&p| to_gltf_axes(p)).collect::<Vec<_>>());
                let indices: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
                assert_eq!(indices, triangles.iter().flatten().copied().collect::<Vec<_>>());
            }
            GlbShape::LineStrip { points } => {
                assert_eq!(prim.mode(), Mode::LineStrip);
                assert!(prim.indices().is_none());
                assert_eq!(positions.len(), points.len());
                assert_eq!(positions, points.iter().map(|&p| to_gltf_axes(p)).collect::<Vec<_>>());
            }
        }
    }
    assert_eq!(doc.nodes().filter(|n| n.mesh().is_some()).count(), 3);
}

#[test]
fn the_axes_turn_z_up_into_y_up() {
    // Up stays up, the world's +y points into glTF's −z, x is kept: a right-handed turn.
    assert_eq!(to_gltf_axes([0.0, 0.0, 1.0]), [0.0, 1.0, 0.0]);
    assert_eq!(to_gltf_axes([0.0, 1.0, 0.0]), [0.0, 0.0, -1.0]);
    assert_eq!(to_gltf_axes([1.0, 0.0, 0.0]), [1.0, 0.0, 0.0]);
    let bytes = glb_bytes(&scene()).unwrap();
    let glb = gltf::Gltf::from_slice(&bytes).unwrap();
    let route = glb.document.meshes().find(|m| m.name() == Some("route")).unwrap();
    let prim = route.primitives().next().unwrap();
    let blob = glb.blob.as_deref().unwrap();
    let points: Vec<[f32; 3]> = prim.reader(|_| Some(blob)).read_positions().unwrap().collect();
    assert_eq!(points, [[-1.0, 0.5, 2.0], [3.0, 0.25, -4.0]]);
}
