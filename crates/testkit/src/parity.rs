//! What the function-level parity tests of the WGSL modules share: the
//! bindings of an evaluation kernel (`eikon_gpu::Eval`), seeded inputs
//! rounded to f32 (what the GPU is given, so that a comparison sees only
//! the arithmetic), and packing to and from the kernel's `vec4<f32>`s.

use eikon_rng::SplitMix64;
use glam::DVec3;

/// The bindings every evaluation kernel starts with.
pub const IO: &str = "
@group(0) @binding(0) var<storage, read> input: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read_write> output: array<vec4<f32>>;
";

/// Seeded inputs: the same cases on every run.
pub struct Cases(SplitMix64);

impl Cases {
    /// The stream of `seed`.
    pub fn new(seed: u64) -> Self {
        Cases(SplitMix64::new(seed))
    }

    /// 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in `[lo, hi)`, rounded to f32.
    pub fn f(&mut self, lo: f64, hi: f64) -> f64 {
        self.0.uniform(lo, hi) as f32 as f64
    }

    /// Each component uniform in `[lo, hi)`, rounded to f32.
    pub fn v(&mut self, lo: f64, hi: f64) -> DVec3 {
        DVec3::new(self.f(lo, hi), self.f(lo, hi), self.f(lo, hi))
    }
}

/// `v` rounded to f32, as the GPU holds it.
pub fn f32s(v: DVec3) -> DVec3 {
    DVec3::new(v.x as f32 as f64, v.y as f32 as f64, v.z as f32 as f64)
}

/// `(v, w)` as a kernel's `vec4<f32>`.
pub fn v4(v: DVec3, w: f64) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, w as f32]
}

/// The `xyz` of a kernel's `vec4<f32>`.
pub fn xyz(a: [f32; 4]) -> DVec3 {
    DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64)
}

/// Integers passed as their bits (`bitcast<vec4<u32>>` in the kernel).
pub fn bits(v: [u32; 4]) -> [f32; 4] {
    v.map(f32::from_bits)
}
