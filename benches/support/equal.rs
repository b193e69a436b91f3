//! What the two time-to-equal-error benches share (`equal_error.rs`
//! against eikon's photons, `equal_error_independent.rs` against the
//! independent tracer): the cell-average quadrature, the score and where
//! a photon sweep reaches an error. Included with `#[path]`.

use ndarray::Array3;

/// 6-point Gauss-Legendre nodes and weights on [-1, 1]: exact cell
/// averages of the smooth truths.
pub const GL6: [(f64, f64); 6] = [
    (-0.932_469_514_203_152, 0.171_324_492_379_170),
    (-0.661_209_386_466_265, 0.360_761_573_048_139),
    (-0.238_619_186_083_197, 0.467_913_934_572_691),
    (0.238_619_186_083_197, 0.467_913_934_572_691),
    (0.661_209_386_466_265, 0.360_761_573_048_139),
    (0.932_469_514_203_152, 0.171_324_492_379_170),
];

/// Photon runs fitted when a sweep ends above the target error.
pub const FIT_POINTS: usize = 3;

/// How an estimate compares with the truth over the scored cells.
#[derive(Clone, Copy)]
pub struct Score {
    /// Mean of |estimate / truth - 1| over the cells and channels.
    pub error: f64,
    /// Mean of estimate / truth - 1.
    pub signed: f64,
    /// Cell-channels with an estimate of 0.
    pub dark: usize,
}

/// [`Score`] of `est` against `truth` (both by `[i, j, k, channel]`) over
/// the cells `scored` marks, the three channels each.
pub fn score(
    scored: &Array3<bool>,
    est: impl Fn([usize; 4]) -> f64,
    truth: impl Fn([usize; 4]) -> f64,
) -> Score {
    let (mut sum, mut signed, mut n, mut dark) = (0.0, 0.0, 0usize, 0usize);
    for ((i, j, k), &m) in scored.indexed_iter() {
        if !m {
            continue;
        }
        for c in 0..3 {
            let e = est([i, j, k, c]);
            dark += usize::from(e == 0.0);
            let rel = e / truth([i, j, k, c]) - 1.0;
            sum += rel.abs();
            signed += rel;
            n += 1;
        }
    }
    Score {
        error: sum / n as f64,
        signed: signed / n as f64,
        dark,
    }
}

/// The median (the upper one of an even count).
pub fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Where the photons reach an error.
pub enum Reach {
    /// Between two measured runs (their counts as powers of two):
    /// log-log interpolation.
    Measured { lo: u32, hi: u32 },
    /// Reached by the first run already: at most its count.
    AtMost,
    /// Beyond the last run: `a N^b` fitted on the last runs from 2^`from`.
    Fitted { a: f64, b: f64, from: u32 },
    /// The fitted error does not fall.
    Never { b: f64 },
    /// Beyond the last run, against a reference of `reference` photons of
    /// the same tracer: `e^2 = a (1/N + 1/reference)` fitted on the last
    /// runs from 2^`from` ([`equal_error_against_photons`]).
    Floored { a: f64, reference: f64, from: u32 },
    /// Below what the reference's own noise allows at any count.
    #[allow(dead_code)]
    BelowFloor { a: f64, reference: f64 },
}

/// The photon count at which the error reaches a target.
pub struct Equal {
    /// Photons.
    pub count: f64,
    /// How it was found.
    pub reach: Reach,
}

/// Photon count at which a sweep of `(photons, error)` runs, in rising
/// counts, reaches `target`.
pub fn equal_error(runs: &[(u64, f64)], target: f64) -> Equal {
    let log2 = |n: u64| n.trailing_zeros();
    if let Some(hi) = runs.iter().position(|r| r.1 <= target) {
        if hi == 0 {
            return Equal {
                count: runs[0].0 as f64,
                reach: Reach::AtMost,
            };
        }
        let (a, b) = (runs[hi - 1], runs[hi]);
        let slope = (b.1 / a.1).ln() / (b.0 as f64 / a.0 as f64).ln();
        return Equal {
            count: a.0 as f64 * (target / a.1).powf(1.0 / slope),
            reach: Reach::Measured {
                lo: log2(a.0),
                hi: log2(b.0),
            },
        };
    }
    let last = &runs[runs.len().saturating_sub(FIT_POINTS)..];
    let xs: Vec<f64> = last.iter().map(|r| (r.0 as f64).ln()).collect();
    let ys: Vec<f64> = last.iter().map(|r| r.1.ln()).collect();
    let n = xs.len() as f64;
    let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
    let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
    let b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    if b >= -1e-3 {
        return Equal {
            count: f64::INFINITY,
            reach: Reach::Never { b },
        };
    }
    let a = (my - b * mx).exp();
    Equal {
        count: (target / a).powf(1.0 / b),
        reach: Reach::Fitted {
            a,
            b,
            from: log2(last[0].0),
        },
    }
}

/// [`equal_error`] for a sweep scored against a reference that is itself
/// `reference` photons of the same tracer (independent of the sweep's):
/// between two measured runs the same log-log interpolation; beyond the
/// last run, not a power law but the model the two noises make. Each
/// cell's relative error is the sweep's noise minus the reference's, both
/// photon noise of one tracer, with variances `k_i^2 / N` and
/// `k_i^2 / reference` in the same proportion over the cells; so the mean
/// absolute error is `sqrt(a (1/N + 1/reference))` for one `a`. A power
/// law fitted where the reference's noise already counts falls too slowly
/// and puts the count too low. The model's `a` also predicts how far two
/// reference runs differ, which a bench can check against the seeds.
#[allow(dead_code)]
pub fn equal_error_against_photons(runs: &[(u64, f64)], target: f64, reference: f64) -> Equal {
    let measured = equal_error(runs, target);
    if !matches!(measured.reach, Reach::Fitted { .. } | Reach::Never { .. }) {
        return measured;
    }
    let last = &runs[runs.len().saturating_sub(FIT_POINTS)..];
    let a = photon_noise(runs, reference);
    let inverse = target * target / a - 1.0 / reference;
    if inverse <= 0.0 {
        return Equal {
            count: f64::INFINITY,
            reach: Reach::BelowFloor { a, reference },
        };
    }
    Equal {
        count: 1.0 / inverse,
        reach: Reach::Floored {
            a,
            reference,
            from: last[0].0.trailing_zeros(),
        },
    }
}

/// The `a` of [`equal_error_against_photons`]' model, `error^2 = a (1/N +
/// 1/reference)`, from the last [`FIT_POINTS`] runs of `(photons, error)`.
#[allow(dead_code)]
pub fn photon_noise(runs: &[(u64, f64)], reference: f64) -> f64 {
    let last = &runs[runs.len().saturating_sub(FIT_POINTS)..];
    last.iter()
        .map(|&(n, e)| e * e / (1.0 / n as f64 + 1.0 / reference))
        .sum::<f64>()
        / last.len() as f64
}

/// `e` in words; `last` is the sweep's last count as a power of two.
pub fn describe(e: &Equal, last: u32) -> String {
    match e.reach {
        Reach::Measured { lo, hi } => {
            format!("measured: log-log interpolation between the runs of 2^{lo} and 2^{hi}")
        }
        Reach::AtMost => "measured: the first run already reaches it (an upper bound)".into(),
        Reach::Fitted { a, b, from } => format!(
            "EXTRAPOLATED beyond the last run (2^{last}): fit error = {a:.3e} * N^({b:.3}) \
             over 2^{from}..2^{last}"
        ),
        Reach::Never { b } => format!("not reached: the fitted slope {b:.3} does not fall"),
        Reach::Floored { a, reference, from } => format!(
            "EXTRAPOLATED beyond the last run (2^{last}) with the reference's noise: \
             error^2 = {a:.3e} (1/N + 1/{reference:.3e}) over 2^{from}..2^{last}"
        ),
        Reach::BelowFloor { a, reference } => {
            format!("not reached: below the reference's own noise, sqrt({a:.3e} / {reference:.3e})")
        }
    }
}
