//! The `gpu` backend of the light simulator (wgpu compute shaders): the
//! whole simulator ([`simulate_light`], [`GpuSimulator`]; see
//! `simulate.rs`), composed from the WGSL modules it shares with the CPU
//! code's definitions and with the view renderer.

mod simulate;
pub use simulate::{
    simulate_light, simulate_light_in, source, GpuSimulator, PyramidLevel, SimParams,
};
