//! Datasets: the canonical Blender/NeRF-synthetic format read and written, and captures read
//! as their tools write them (instant-ngp and nerfstudio `transforms.json`, COLMAP models).
//!
//! A Blender dataset folder holds `transforms_{train,val,test}.json` (`camera_angle_x` and
//! frames with `file_path` and a 4×4 camera-to-world `transform_matrix`, OpenGL camera axes),
//! RGBA PNGs and, per frame, a 16-bit ground-truth depth PNG in millimetres named by
//! `depth_file_path` (nerfstudio's convention). [`load_split`] reads it, a `transforms.json`
//! (with nerfstudio's `camera_model`, OpenCV distortion and split lists) and a COLMAP folder
//! ([`colmap`]), PNG or JPEG images, undistorting OpenCV cameras into pinhole ones
//! ([`distortion`]); [`Placement`] puts a capture in the study's metric, z-up world;
//! [`write_split`] writes the Blender format atomically.
//!
//! ```no_run
//! use nerfsv_dataset::{load_split, LoadOptions};
//! let train = load_split("/tmp/ds".as_ref(), "train", LoadOptions::default()).unwrap();
//! let frame = &train.frames[0];
//! let ray = frame.camera.pixel_ray(10, 20); // world-space ray through pixel (10, 20)
//! let rgba = frame.image.pixel(10, 20);
//! # let _ = (ray, rgba);
//! ```

pub mod camera_path;
pub mod colmap;
pub mod distortion;
pub mod error;
pub mod folder;
pub mod generate;
pub mod linked;
pub mod placement;
pub mod split;
pub mod transforms;
pub mod writer;

pub use camera_path::{load_camera_path, CameraPath};
pub use distortion::OpenCvDistortion;
pub use error::DatasetError;
pub use folder::{dataset_files, dataset_format, has_split, load_split, probe, DatasetFormat};
pub use generate::{generate, render, sample_cameras, DatasetFigures, GenerateOptions};
pub use linked::{load_all_frames, load_linked_split, LinkedFolder, LINK_FILE};
pub use nerfsv_scene::image::{DepthImage, Image};
pub use placement::Placement;
pub use split::{Frame, LoadOptions, Split};
pub use writer::{write_split, FrameToWrite};

/// The split names of the Blender format, in the order they are written.
pub const SPLITS: [&str; 3] = ["train", "val", "test"];
