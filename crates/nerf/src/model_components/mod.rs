//! Parts of the model around the field: occupancy grid, ray sampler, volume renderer, losses.

pub mod losses;
pub mod occupancy_grid;
pub mod ray_samplers;
pub mod renderer;
