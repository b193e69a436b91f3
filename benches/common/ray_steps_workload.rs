//! The workload of the `ray_steps` bench, shared with
//! `examples/ray_steps_ir.rs` (instruction counts) so both measure the same
//! rays: a 128^3 voxelized Luneburg lens and a 16 x 16 fan of parallel rays
//! across it, along +z from the bounds.

use glam::DVec3;

/// The scene: a Luneburg lens of radius 0.8 in [-1, 1]^3.
pub const SCENE: &str = r#"
[grid]
resolution = 128
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = 0.8 }
index = { type = "luneburg" }
"#;

/// The fan's origins (each ray goes along +z).
pub fn origins() -> Vec<DVec3> {
    (0..256)
        .map(|i| {
            let (a, b) = ((i % 16) as f64 / 15.0, (i / 16) as f64 / 15.0);
            DVec3::new(1.6 * a - 0.8, 1.6 * b - 0.8, -1.0)
        })
        .collect()
}
