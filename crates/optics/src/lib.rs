//! # eikon-optics
//!
//! The optics both the eikonal renderer and the exact mesh renderers use,
//! none of which needs a voxel grid:
//!
//! * [`fresnel`]: reflection, transmission and refraction at a dielectric
//!   interface ([Ihrke07 eqs 2 and 5]);
//! * [`phase`]: the Henyey-Greenstein phase function [Ihrke07 eqs 3 and 6];
//! * [`camera`]: the look-at pinhole camera and its stratified sampling;
//! * [`environment`]: latitude-longitude environment maps and the sky;
//! * [`spot`]: a spot light's cone weight;
//! * [`image`]: HDR images, OpenEXR and tone-mapped PNG.

pub mod camera;
pub mod environment;
pub mod fresnel;
pub mod image;
pub mod phase;
pub mod spot;

pub use camera::{Camera, CameraError};
pub use environment::{Environment, EnvironmentError, LatLongMap, Sky};
pub use image::{encode_exr, encode_png, tonemapped, Exposure, Image, ImageError, ToneMap};
pub use phase::hg;
