//! # eikon-exact
//!
//! Exact renderers of media bounded by triangle meshes, the references the
//! eikonal renderer is compared with. They work on the mesh itself, never
//! on a voxel grid:
//!
//! * [`snell`]: a Snell tracer through nested dielectrics (Schmidt & Budge
//!   2002), interior lists over `eikon-mesh` BVHs;
//! * [`walter`]: refracted connections through one boundary (Walter et
//!   al. 2009): the solvers and the position-normal tree;
//! * [`holzschuch`]: per-triangle integration along a refracted camera
//!   segment (Holzschuch 2015);
//! * [`single`]: the single-scattering renderer over them.

pub mod holzschuch;
pub mod single;
pub mod snell;
pub mod walter;
