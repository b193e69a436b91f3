//! Agreement measures shared by the tests.

use eikon_optics::image::log_average_luminance;
use eikon_optics::Image;
use eikon_wavefront::LightVolume;
use glam::DVec3;

/// The median of `v` (the upper one of an even count); NaN if empty.
pub fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// PSNR (dB) of `b` against `a` after the same tone curve on both:
/// exposure `k = 0.18 / ` the log-average luminance of `a`, then
/// `y = kx / (1 + kx)` per channel (peak 1). Non-finite values count as
/// the largest error.
pub fn psnr(a: &Image, b: &Image) -> f64 {
    let k = 0.18 / log_average_luminance(a).unwrap_or(1.0).max(1e-9);
    let t = |x: f32| {
        let y = k * x as f64;
        y / (1.0 + y)
    };
    let mut se = 0.0;
    for (p, q) in a.data.iter().zip(&b.data) {
        for c in 0..3 {
            let d = t(p[c]) - t(q[c]);
            se += if d.is_finite() { d * d } else { 1.0 };
        }
    }
    let mse = se / (3 * a.data.len()) as f64;
    10.0 * (1.0 / mse.max(1e-30)).log10()
}

/// Relative difference of two counts (0 when both are 0).
pub fn count_difference(a: u64, b: u64) -> f64 {
    a.abs_diff(b) as f64 / a.max(b).max(1) as f64
}

/// How far apart two light volumes are, over the cells lit in either.
#[derive(Debug)]
pub struct Agreement {
    /// Cells lit in the CPU's volume.
    pub lit_cpu: usize,
    /// Cells lit in the GPU's.
    pub lit_gpu: usize,
    /// Cells lit in one volume only.
    pub lit_differs: usize,
    /// Median of |gpu / cpu - 1| over cells lit in both (channel sum).
    pub median: f64,
    /// Fraction of cells lit in both within 1%.
    pub within_1: f64,
    /// ... and within 10%.
    pub within_10: f64,
    /// Fraction of cells lit in both whose flux vectors (group 0) point
    /// within 1 degree of each other.
    pub aligned: f64,
    /// Median of |F_gpu - F_cpu| / |F_cpu| over the cells with a flux
    /// vector, over every group.
    pub flux_median: f64,
    /// The fraction of them within 1%.
    pub flux_within_1: f64,
}

/// How far apart `gpu` is from `cpu` (see [`Agreement`]).
pub fn agreement(cpu: &LightVolume, gpu: &LightVolume) -> Agreement {
    let (mut errs, mut lit_cpu, mut lit_gpu, mut lit_differs, mut aligned) =
        (Vec::new(), 0, 0, 0, 0);
    let mut flux_errs = Vec::new();
    let shape = cpu.fluence.shape();
    let vec = |v: &LightVolume, g: usize, i, j, k| {
        DVec3::new(
            v.flux[g][[i, j, k, 0]] as f64,
            v.flux[g][[i, j, k, 1]] as f64,
            v.flux[g][[i, j, k, 2]] as f64,
        )
    };
    for i in 0..shape[0] {
        for j in 0..shape[1] {
            for k in 0..shape[2] {
                let sum =
                    |v: &LightVolume| (0..3).map(|c| v.fluence[[i, j, k, c]] as f64).sum::<f64>();
                let (a, b) = (sum(cpu), sum(gpu));
                lit_cpu += usize::from(a > 0.0);
                lit_gpu += usize::from(b > 0.0);
                if (a > 0.0) != (b > 0.0) {
                    lit_differs += 1;
                }
                if a > 0.0 && b > 0.0 {
                    errs.push((b / a - 1.0).abs());
                    let d = |v: &LightVolume| vec(v, 0, i, j, k).normalize_or_zero();
                    if d(cpu).dot(d(gpu)) > 1f64.to_radians().cos() {
                        aligned += 1;
                    }
                }
                for g in 0..cpu.flux.len() {
                    let (fc, fg) = (vec(cpu, g, i, j, k), vec(gpu, g, i, j, k));
                    if fc.length() > 0.0 {
                        flux_errs.push((fg - fc).length() / fc.length());
                    }
                }
            }
        }
    }
    let n = errs.len() as f64;
    let nf = flux_errs.len() as f64;
    Agreement {
        lit_cpu,
        lit_gpu,
        lit_differs,
        within_1: errs.iter().filter(|&&e| e <= 0.01).count() as f64 / n,
        within_10: errs.iter().filter(|&&e| e <= 0.1).count() as f64 / n,
        aligned: aligned as f64 / n,
        median: median(errs),
        flux_within_1: flux_errs.iter().filter(|&&e| e <= 0.01).count() as f64 / nf,
        flux_median: median(flux_errs),
    }
}
