//! The GPU backend against the CPU one. These tests need a Vulkan, Metal
//! or DX12 adapter: CI installs Mesa's lavapipe and sets `CI` and
//! `WGPU_BACKEND=vulkan`, and there a missing adapter fails the test
//! instead of skipping it.

use eikon_gpu::Gpu;
use eikon_wavefront::gpu::GpuHistoPyramid;
use eikon_wavefront::HistoPyramid;

fn gpu() -> Option<Gpu> {
    match Gpu::new() {
        Ok(g) => {
            println!("adapter: {}", g.describe());
            if std::env::var("WGPU_BACKEND").is_ok_and(|b| b.eq_ignore_ascii_case("vulkan")) {
                assert_eq!(g.info.backend, wgpu::Backend::Vulkan, "{}", g.describe());
            }
            Some(g)
        }
        Err(e) => {
            assert!(
                std::env::var_os("CI").is_none(),
                "CI must have a GPU adapter (lavapipe): {e}"
            );
            eprintln!("skipped (no GPU adapter here): {e}");
            None
        }
    }
}

/// A seeded xorshift, so the cases are the same on every run.
fn counts(n: usize, seed: u64, mix: [u32; 3]) -> Vec<u8> {
    let mut s = seed.max(1);
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let r = (s % (mix[0] + mix[1] + mix[2]) as u64) as u32;
            if r < mix[0] {
                0
            } else if r < mix[0] + mix[1] {
                1
            } else {
                4
            }
        })
        .collect()
}

#[test]
fn gpu_histopyramid_equals_the_cpu_one() {
    let Some(gpu) = gpu() else { return };
    let hp = GpuHistoPyramid::new(&gpu).unwrap();
    let mut cpu = HistoPyramid::new();
    let mut cases: Vec<Vec<u8>> = vec![
        vec![],
        vec![0],
        vec![4],
        vec![0; 1000],
        vec![4; 4097],
        vec![1; 65],
    ];
    for (i, n) in [
        1usize, 3, 5, 17, 63, 64, 65, 255, 1023, 4099, 100_003, 1_000_001,
    ]
    .into_iter()
    .enumerate()
    {
        cases.push(counts(n, 7 + i as u64, [1, 5, 1]));
        cases.push(counts(n, 99 + i as u64, [3, 1, 3]));
    }
    let mut slots = 0;
    for c in &cases {
        cpu.build(c);
        let (mut src, mut part) = (Vec::new(), Vec::new());
        cpu.expand_into(&mut src, &mut part);
        let (gsrc, gpart) = hp.compact_expand(c).unwrap();
        assert_eq!(gsrc.len(), src.len(), "{} counts", c.len());
        assert!(gsrc == src, "sources differ for {} counts", c.len());
        assert!(gpart == part, "parts differ for {} counts", c.len());
        slots += src.len();
    }
    println!("{} cases, {slots} output slots: GPU == CPU", cases.len());
}
