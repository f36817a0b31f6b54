//! Datasets in the canonical Blender/NeRF-synthetic format.
//!
//! A dataset folder holds `transforms_{train,val,test}.json` (`camera_angle_x` and frames with
//! `file_path` and a 4×4 camera-to-world `transform_matrix`, OpenGL camera axes), RGBA PNGs and,
//! per frame, a 16-bit ground-truth depth PNG in millimetres named by `depth_file_path`
//! (nerfstudio's convention). [`load_split`] reads it, and also the instant-ngp/nerfstudio
//! variants; [`write_split`] writes it atomically.
//!
//! ```no_run
//! use nerfsv_dataset::{load_split, LoadOptions};
//! let train = load_split("/tmp/ds".as_ref(), "train", LoadOptions::default()).unwrap();
//! let frame = &train.frames[0];
//! let ray = frame.camera.pixel_ray(10, 20); // world-space ray through pixel (10, 20)
//! let rgba = frame.image.pixel(10, 20);
//! # let _ = (ray, rgba);
//! ```

pub mod error;
pub mod generate;
pub mod transforms;
pub mod writer;

pub use error::DatasetError;
pub use generate::{generate, sample_cameras, GenerateOptions};
pub use nerfsv_scene::image::{DepthImage, Image};
pub use transforms::{dataset_files, load_split, Frame, LoadOptions, Split};
pub use writer::{write_split, FrameToWrite};

/// The split names of the Blender format, in the order they are written.
pub const SPLITS: [&str; 3] = ["train", "val", "test"];
