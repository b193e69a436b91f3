//! # eikon-wavefront
//!
//! Light simulation by adaptive wavefront tracing (Ihrke et al. 2007,
//! sections 4.2 and 5.2). This crate is being built up in the order of the
//! light-simulation issue; so far it holds the data-parallel list rebuild
//! the simulation runs after every step:
//!
//! * [`histopyramid`]: compaction and expansion of the patch list (each
//!   patch eliminated, retained or tessellated into four).

pub mod histopyramid;

pub use histopyramid::HistoPyramid;
