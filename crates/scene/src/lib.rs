//! Ground-truth worlds for nerfsv: analytic signed distance functions in metres (z up), a
//! sphere-tracing renderer with procedural textures and exact depth, and the camera, geometry
//! and image types every later stage shares (with [`PosedImages`], the views a model learns from).
//!
//! ```
//! use nalgebra::{Point3, Vector3};
//! use nerfsv_scene::{Camera, Intrinsics, RenderSettings, Scene};
//! let scene = Scene::builtin("stonehenge").unwrap();
//! assert!(scene.distance(&Point3::new(0.0, 0.0, 2.0)) > 1.0); // high above everything
//! let cam = Camera::look_at(Point3::new(3.0, -3.0, 2.0), Point3::origin(), Vector3::z(),
//!                           Intrinsics::from_fov_x(16, 16, 0.8));
//! let img = scene.render(&cam, &RenderSettings::default());
//! assert_eq!(img.rgba.len(), 16 * 16 * 4);
//! ```

pub mod animation;
pub mod camera;
pub mod folder;
pub mod geometry;
pub mod image;
pub mod io;
pub mod mesh;
pub mod render;
pub mod scenes;
pub mod sdf;
pub mod seed;
pub mod stats;
pub mod texture;
pub mod validate;
pub mod views;

pub use camera::{Camera, Intrinsics};
pub use geometry::{Aabb, Ray};
pub use image::{DepthImage, Image};
pub use render::{Hit, RenderSettings, RenderedImage};
pub use scenes::{Scene, SceneError, BUILTIN_SCENES};
pub use sdf::{Material, Shape};
pub use validate::{InvalidValue, MemoryBudget};
pub use views::{PosedImages, View};
