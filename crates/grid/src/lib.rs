//! # eikon-grid
//!
//! The refractive medium on a voxel grid and the ray equation of geometric
//! optics ([Ihrke07 secs 3-4] and its appendix).
//!
//! * [`scene`]: TOML scene files (grid, ambient medium, objects, lights).
//! * [`shape`] and [`object`]: solids with materials and priorities; overlaps
//!   are resolved as in Schmidt & Budge's nested dielectrics.
//! * [`voxelize`](crate::field::Medium::build) and [`field`]: supersampled
//!   rasterization, Gaussian smoothing, gradient, boundary indicator, and
//!   trilinear or exact analytic sampling.
//! * [`ray`]: [Ihrke07 eqs 9-10 and 14-15] with Euler, RK4 and Dormand-Prince.
//! * [`vdb`]: OpenVDB export (our own writer) and import of float grids.

pub mod animation;
pub mod blocks;
pub mod error;
pub mod field;
pub mod geometry;
pub mod interface;
pub mod mesh_solid;
pub mod object;
pub mod profile;
pub mod ray;
pub mod region;
pub mod scene;
pub mod shape;
mod smooth;
pub mod surface;
pub mod vdb;
mod voxelize;

pub use error::{Error, Location, Result};
pub use field::{AnalyticField, BuildProgress, EmptySpace, Medium, MemoryEstimate, VoxelField};
pub use geometry::{GridGeometry, Trilinear};
pub use mesh_solid::MeshSolid;
pub use object::{GridExtinction, GridIndex, IndexProfile, Material, Object};
pub use ray::{
    trace, trace_many, Form, IndexField, Integrator, RayEnd, RayState, Status, TraceOptions,
};
pub use region::{Interfaces, Regions};
pub use scene::{Background, CameraSettings, GridOverride, Light, Receiver, RenderSettings, Scene};
pub use shape::Shape;
pub use surface::Crossing;

/// Progress of a long computation over many items: `(done, total)` or the
/// like, the caller's docs say which two counts (the light simulation's
/// step and live patches, the renderer's tiles done and in all); called
/// from worker threads.
pub type Progress<'a> = &'a (dyn Fn(usize, usize) + Sync);
