//! The view renderer ([Ihrke07 secs 3 and 5.3]): curved eye
//! rays through the voxelized medium, lit by the light volumes.

pub mod background;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod macrocell;
pub mod properties;
pub mod render;

pub use background::Surroundings;
pub use render::{Options, Renderer, Stats};
