//! [`UqError`]: what went wrong, naming the image or the config key.

use nerfsv_scene::validate::InvalidValue;

#[derive(Debug, thiserror::Error)]
pub enum UqError {
    /// A config value out of range (the field is the key, e.g. `uq.noise_std`).
    #[error(transparent)]
    Config(#[from] InvalidValue),
    /// Every ray of the image misses the model's box (or crosses only empty occupancy cells):
    /// there is nothing to fit.
    #[error("{image}: all {rays} rays miss the model (no ray composites a sample inside its box)")]
    AllRaysMiss { image: String, rays: usize },
    /// Rays and reference colours do not pair up.
    #[error("{image}: {rays} rays but {references} reference colours")]
    LengthMismatch { image: String, rays: usize, references: usize },
    /// A reference colour that is NaN or infinite.
    #[error("{image}: reference colour of pixel {pixel} is not finite ({value:?})")]
    NonFiniteReference { image: String, pixel: usize, value: [f32; 3] },
    /// The fitted quantities are not finite (a diverged model).
    #[error("{image}: {what} is not finite")]
    NonFinite { image: String, what: &'static str },
    /// The Hessian at the mode could not be factorised (only possible with a non-finite one).
    #[error("{image}: the Hessian of the log posterior is not positive definite")]
    NotPositiveDefinite { image: String },
}
