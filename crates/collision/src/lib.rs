pub mod grid;
pub mod mc_tables;
pub use grid::{GridGeometry, GridQuery, ScalarGrid};

#[derive(Debug, thiserror::Error)]
pub enum CollisionError {
    #[error("invalid grid geometry: {0}")]
    InvalidGeometry(String),
    #[error("grid data has {found} values, expected {expected}")]
    DataLength { expected: usize, found: usize },
}
