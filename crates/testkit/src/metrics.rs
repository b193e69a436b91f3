//! Agreement measures shared by the tests.

use eikon_optics::image::log_average_luminance;
use eikon_optics::Image;

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
