//! The view renderer (Ihrke et al. 2007, sections 3 and 5.3).

pub mod camera;
pub mod environment;
pub use eikon_grid::fresnel;
pub mod gpu;
pub mod image;
pub mod phase;

pub use camera::{Camera, CameraError};
pub use environment::{Environment, EnvironmentError, LatLongMap, Sky};
pub use image::{encode_exr, encode_png, tonemapped, Exposure, Image, ImageError, ToneMap};
pub use phase::hg;
pub mod background;
pub mod holzschuch;
pub mod macrocell;
pub mod properties;
pub mod render;
pub mod single;
pub mod snell;
pub mod walter;

pub use background::Surroundings;
pub use render::{Options, Renderer, Stats};
