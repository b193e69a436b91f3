//! The `gpu` backend of the light simulator (wgpu compute shaders). It
//! shares the CPU backend's definitions: the same counts (0, 1, 4), the
//! same pyramid layout and the same walk, so the two give identical lists.
//!
//! The whole simulator ([`simulate_light`], [`GpuSimulator`]; see
//! `simulate.rs`) and its HistoPyramid on its own ([`GpuHistoPyramid`]),
//! checked against the CPU in `tests/gpu.rs`.

use eikon_gpu::{groups, Gpu, GpuError};

mod simulate;
pub use simulate::{simulate_light, GpuSimulator};

const REDUCE: &str = include_str!("histopyramid.wgsl");
const EXPAND: &str = include_str!("expand.wgsl");

/// The HistoPyramid's kernels on one device.
pub struct GpuHistoPyramid<'a> {
    gpu: &'a Gpu,
    reduce: wgpu::ComputePipeline,
    expand: wgpu::ComputePipeline,
}

/// Level offsets and lengths of a pyramid over `n` counts (level 0 first).
fn layout(n: usize) -> (Vec<u32>, Vec<u32>) {
    let mut lens = vec![n.max(1) as u32];
    while *lens.last().expect("non-empty") > 1 {
        let l = lens.last().expect("non-empty").div_ceil(4);
        lens.push(l);
    }
    let mut offsets = Vec::with_capacity(lens.len());
    let mut at = 0u32;
    for &l in &lens {
        offsets.push(at);
        at += l;
    }
    (offsets, lens)
}

impl<'a> GpuHistoPyramid<'a> {
    /// Compile the kernels on `gpu`.
    pub fn new(gpu: &'a Gpu) -> Result<Self, GpuError> {
        Ok(Self {
            gpu,
            reduce: gpu.pipeline("histopyramid reduce", REDUCE, "reduce")?,
            expand: gpu.pipeline("histopyramid expand", EXPAND, "expand")?,
        })
    }

    /// Build the pyramid over `counts` on the GPU and walk every output
    /// slot: returns `(source, part)` as the CPU
    /// [`HistoPyramid::expand_into`](crate::HistoPyramid::expand_into)
    /// does. Only the total is read back before the walk.
    pub fn compact_expand(&self, counts: &[u8]) -> Result<(Vec<u32>, Vec<u8>), GpuError> {
        let gpu = self.gpu;
        let (offsets, lens) = layout(counts.len());
        let depth = lens.len();
        let size: u32 = lens.iter().sum();
        let mut base: Vec<u32> = counts.iter().map(|&c| c as u32).collect();
        base.resize(size as usize, 0);
        let levels = gpu.storage("histopyramid levels", &base);
        let mut info = vec![depth as u32];
        info.extend(&offsets);
        info.extend(&lens);
        let info_buf = gpu.storage("histopyramid info", &info);
        // Reduction: one dispatch per level, in order.
        gpu.checked("histopyramid reduce", || {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            let uniforms: Vec<eikon_gpu::Buffer> = (1..depth)
                .map(|l| {
                    gpu.uniform(
                        "histopyramid level",
                        &[offsets[l - 1], lens[l - 1], offsets[l], lens[l]],
                    )
                })
                .collect();
            for (l, u) in (1..depth).zip(&uniforms) {
                let bind = gpu.bind(&self.reduce, &[&levels, u]);
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.reduce);
                pass.set_bind_group(0, &bind, &[]);
                let (x, y) = groups(lens[l] as usize);
                pass.dispatch_workgroups(x, y, 1);
            }
            gpu.queue.submit([enc.finish()]);
        })?;
        // The CPU reads back only the new list's length.
        let total = {
            let top = gpu.storage_empty("histopyramid top", 4);
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            enc.copy_buffer_to_buffer(&levels, offsets[depth - 1] as u64 * 4, &top, 0, 4);
            gpu.queue.submit([enc.finish()]);
            gpu.read::<u32>(&top, 1)?[0] as usize
        };
        if total == 0 {
            return Ok((Vec::new(), Vec::new()));
        }
        let source = gpu.storage_empty("histopyramid source", total as u64 * 4);
        let part = gpu.storage_empty("histopyramid part", total as u64 * 4);
        gpu.checked("histopyramid expand", || {
            let bind = gpu.bind(&self.expand, &[&levels, &info_buf, &source, &part]);
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.expand);
                pass.set_bind_group(0, &bind, &[]);
                let (x, y) = groups(total);
                pass.dispatch_workgroups(x, y, 1);
            }
            gpu.queue.submit([enc.finish()]);
        })?;
        let src = gpu.read::<u32>(&source, total)?;
        let parts = gpu.read::<u32>(&part, total)?;
        Ok((src, parts.into_iter().map(|p| p as u8).collect()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_matches_the_cpu_levels() {
        let (o, l) = layout(17);
        assert_eq!(l, vec![17, 5, 2, 1]);
        assert_eq!(o, vec![0, 17, 22, 24]);
        assert_eq!(layout(0).1, vec![1]);
        assert_eq!(layout(4).1, vec![4, 1]);
    }
}
