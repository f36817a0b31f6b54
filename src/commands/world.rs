use std::path::{Path, PathBuf};

use clap::Args;
use nerfsv_scene::mesh::{MeshOptions, UpAxis};
use nerfsv_scene::Scene;

/// How a mesh file becomes metres, z up.
#[derive(Args, Clone)]
pub struct MeshArgs {
    /// Metres per unit of the mesh file.
    #[arg(long, default_value_t = 1.0)]
    pub mesh_scale: f32,
    /// Which axis of the mesh file points up (a signed axis: `--mesh-up -y` for a y-down file).
    #[arg(long, value_enum, default_value = "z", allow_hyphen_values = true)]
    pub mesh_up: UpAxis,
}

impl MeshArgs {
    pub fn options(&self) -> MeshOptions {
        MeshOptions { scale: self.mesh_scale, up: self.mesh_up }
    }
}

/// The mesh scene of `path`, its warnings printed on stderr.
pub fn load_mesh_scene(path: &Path, args: &MeshArgs) -> anyhow::Result<Scene> {
    let (scene, warnings) = Scene::load_mesh(path, args.options())?;
    for w in warnings {
        eprintln!("warning: {w}");
    }
    Ok(scene)
}

/// A built-in scene or a mesh file: the ground truth a command renders or builds a field of.
#[derive(Args)]
pub struct WorldArgs {
    /// Built-in scene: stonehenge, monolith or pillars.
    #[arg(long, default_value = "stonehenge", conflicts_with = "mesh")]
    pub scene: String,
    /// A triangle mesh as the world instead (OBJ with MTL colours and PNG textures, PLY with
    /// vertex colours, glTF 2.0 / GLB), in metres with z up unless --mesh-scale / --mesh-up say
    /// otherwise; centred on the origin like the built-in scenes, whose camera placement it
    /// shares.
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    #[command(flatten)]
    pub mesh_options: MeshArgs,
}

impl WorldArgs {
    pub fn load(&self) -> anyhow::Result<Scene> {
        match &self.mesh {
            Some(path) => load_mesh_scene(path, &self.mesh_options),
            None => Ok(Scene::builtin(&self.scene)?),
        }
    }
}
