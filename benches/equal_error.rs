//! Time to equal irradiance error, wavefront vs the photon baseline:
//! `cargo bench --bench equal_error` (a plain `main`; about two minutes
//! on the 2-core development VM, release profile, all cores).
//!
//! # What it measures
//! For point-light scenes with an analytic answer: the irradiance error of
//! [`simulate_light`]; then the error of [`simulate_photons`] with
//! N = 2^14, 2^15, ..., 2^22 photons (seed 1), stopping early once it is
//! at most the wavefront's (or at a time cap, `PHOTON_CAP_S`, a guard
//! against a very slow machine). The photon count N* at the wavefront's
//! error is interpolated in log-log between the two runs around it, or,
//! where the sweep ends first, extrapolated from `a N^b` fitted (least
//! squares in log-log) to its last three runs; the output says which, with
//! the fit.
//! The draws are stratified (see `eikon_wavefront::photons`), so the error
//! falls faster than the `1/sqrt(N)` of independent photons; the
//! `1/sqrt(N)` extrapolation, which would inflate the ratio, is printed for
//! comparison only.
//!
//! The times: the wavefront (medium built beforehand) and a fixed photon
//! run (2^19 photons, or the last count if smaller) are timed in
//! alternation, three times each, because timings drift on a shared
//! machine. The result is the ratio
//!
//! `N* x (median photon run time / its N)  /  median wavefront time`
//!
//! against the goal of >= 20x. The sweep's own run times are
//! printed too.
//!
//! # Scenes
//! A 64^3 grid on [-1, 1]^3, index 1 everywhere, a point light of 1 W per
//! channel. Exact irradiance: `E(x) = P / (4 pi r^2) exp(-sigma l)`, with
//! `r = |x - p|` and `l` the part of the segment from the light to `x`
//! inside the volume (extinction is zero outside the bounds for both
//! methods).
//! * `vacuum`: the light inside the volume, no extinction. Both methods
//!   take their straight empty-space steps.
//! * `absorbing`: ambient extinction 0.5 per unit and the light outside the
//!   volume, in front of its -x face, so that every ray enters through
//!   that face (`l` is smooth across the volume). Both methods take the
//!   general path: RK4 steps and [Ihrke07 eq 18]'s attenuation. The light sits
//!   outside because, at the time of writing, both methods start a light's
//!   rays on the sphere of one voxel around it with the full power: a
//!   light *inside* absorbing matter then reads `exp(sigma h) - 1` (1.6%
//!   at sigma 0.5, h = 1/32) high in both, a shared bias that would hide
//!   the comparison.
//!
//! # Error
//! The mean over the three channels and over the cells whose centre lies
//! more than 3 voxels from the light of `|estimate / exact - 1|`. Both
//! methods estimate the cell average of the fluence (the wavefront's
//! track-length deposit and the photons' track-length estimator), so both
//! are scored against the exact cell average (6^3-point Gauss-Legendre).
//! The table also shows both against the value at the cell centre.
//! A cell with an estimate of 0 (never reached) counts with error 1; the
//! table shows how many there are.

use eikon_grid::{GridGeometry, Medium, Scene};
use eikon_wavefront::photons::simulate_photons;
use eikon_wavefront::{simulate_light, Options};
use glam::DVec3;
use ndarray::{Array3, Array4};
use rayon::prelude::*;
use std::f64::consts::PI;
use std::time::Instant;

#[path = "support/equal.rs"]
mod equal;
use equal::{equal_error, median, Equal, Reach, Score, GL6};

/// Photon counts of the sweep, as powers of two: a fixed schedule, so that
/// the errors and the fit do not depend on the machine's load.
const FIRST_LOG2: u32 = 14;
const LAST_LOG2: u32 = 22;
/// A guard on a slow machine: photon time allowed per scene, s (the sweep
/// stops before a run that would exceed it).
const PHOTON_CAP_S: f64 = 120.0;
/// Photon count (as a power of two, at most the last run's) timed side by
/// side with the wavefront for the cost per photon.
const SIDE_LOG2: u32 = 19;
/// Cells closer to the light than this many voxels are not scored.
const EXCLUDE_VOXELS: f64 = 3.0;

/// An analytic scene.
struct Case {
    name: &'static str,
    what: &'static str,
    light: DVec3,
    sigma: f64,
}

const CASES: [Case; 2] = [
    Case {
        name: "vacuum",
        what: "point light inside, no extinction",
        light: DVec3::new(0.137, -0.211, 0.073),
        sigma: 0.0,
    },
    Case {
        name: "absorbing",
        what: "point light 0.45 before the -x face, ambient extinction 0.5 / unit",
        light: DVec3::new(-1.45, 0.23, -0.17),
        sigma: 0.5,
    },
];

/// Exact irradiance at `x` of a 1 W point light at `p` in the volume `g`
/// filled with extinction `sigma` (clear outside it).
fn exact(g: &GridGeometry, p: DVec3, sigma: f64, x: DVec3) -> f64 {
    let d = x - p;
    let r = d.length();
    // The segment p + t d, t in [0, 1], is inside the bounds from t0 on
    // (x itself is inside).
    let t0 = g.clip_line(p, d).map_or(0.0, |(t0, _)| t0.clamp(0.0, 1.0));
    (-sigma * r * (1.0 - t0)).exp() / (4.0 * PI * r * r)
}

/// Per-cell exact values: at the centre, and the cell average.
fn truth(g: &GridGeometry, p: DVec3, sigma: f64) -> (Array3<f64>, Array3<f64>) {
    let [nx, ny, nz] = g.dims;
    let half = g.spacing() * 0.5;
    let cell = |q: usize| (q / (ny * nz), (q / nz) % ny, q % nz);
    let centre: Vec<f64> = (0..nx * ny * nz)
        .into_par_iter()
        .map(|q| {
            let (i, j, k) = cell(q);
            exact(g, p, sigma, g.voxel_center(i, j, k))
        })
        .collect();
    let average: Vec<f64> = (0..nx * ny * nz)
        .into_par_iter()
        .map(|q| {
            let (i, j, k) = cell(q);
            let c = g.voxel_center(i, j, k);
            let mut s = 0.0;
            for (a, wa) in GL6 {
                for (b, wb) in GL6 {
                    for (d, wd) in GL6 {
                        let x = c + DVec3::new(a, b, d) * half;
                        s += wa * wb * wd * exact(g, p, sigma, x);
                    }
                }
            }
            s / 8.0
        })
        .collect();
    let shape = (nx, ny, nz);
    (
        Array3::from_shape_vec(shape, centre).expect("centre values fit the grid"),
        Array3::from_shape_vec(shape, average).expect("cell averages fit the grid"),
    )
}

/// [`equal::score`] of a volume against an exact field (the same for
/// every channel).
fn score(est: &Array4<f32>, exact: &Array3<f64>, scored: &Array3<bool>) -> Score {
    equal::score(
        scored,
        |[i, j, k, c]| est[[i, j, k, c]] as f64,
        |[i, j, k, _]| exact[[i, j, k]],
    )
}

/// One photon run.
struct Run {
    count: usize,
    entered: usize,
    time: f64,
    /// Against the cell averages (what the estimator estimates).
    average: Score,
    /// Against the centre values.
    centre: Score,
}

fn secs(t: f64) -> String {
    if t.is_finite() {
        format!("{t:.1} s")
    } else {
        "never".into()
    }
}

fn time_wavefront(scene: &Scene, medium: &Medium) -> (f64, Array4<f32>) {
    let t = Instant::now();
    let (volume, _) = simulate_light(&scene.lights[0], medium, &Options::default(), &|_, _| {})
        .expect("the wavefront simulation runs");
    (t.elapsed().as_secs_f64(), volume.fluence)
}

/// What one scene gave, for the summary.
struct Outcome {
    name: &'static str,
    /// Wavefront time (median of the side-by-side runs), s.
    time: f64,
    /// Wavefront error (the target).
    error: f64,
    /// Where the photons reach it.
    photons: Equal,
    /// Photon time there, s.
    photon_time: f64,
}

/// Run one scene: its table and lines, and its outcome.
fn run_case(case: &Case) -> Outcome {
    let text = format!(
        "[grid]\nresolution = 64\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
         [ambient]\nindex = 1.0\nextinction = [{s}, {s}, {s}]\n\
         [[light]]\ntype = \"point\"\nposition = [{}, {}, {}]\npower = [1, 1, 1]\n",
        case.light.x,
        case.light.y,
        case.light.z,
        s = case.sigma
    );
    let scene = Scene::parse(&text, case.name).expect("the benchmark scene parses");
    let medium = Medium::build(&scene).expect("the benchmark medium builds");
    let g = &medium.geometry;
    let h = g.voxel_size();
    let p = case.light;
    let (centre, average) = truth(g, p, case.sigma);
    let scored = Array3::from_shape_fn(centre.dim(), |(i, j, k)| {
        (g.voxel_center(i, j, k) - p).length() > EXCLUDE_VOXELS * h
    });
    let cells = scored.iter().filter(|&&s| s).count();

    println!();
    println!(
        "== {}: {}; light at ({}, {}, {}) ==",
        case.name, case.what, p.x, p.y, p.z
    );
    println!(
        "   {} of {} cells scored (centre > {EXCLUDE_VOXELS} voxels from the light), 3 channels",
        cells,
        g.voxel_count()
    );

    let (t_first, wf) = time_wavefront(&scene, &medium);
    let wf_centre = score(&wf, &centre, &scored);
    let wf_average = score(&wf, &average, &scored);

    println!(
        "   {:<10} {:>9} {:>9} {:>9} | {:>21} | {:>21} | {:>5}",
        "method",
        "N",
        "entered",
        "time",
        "err vs centre (signed)",
        "err vs average (signed)",
        "dark"
    );
    let row = |name: &str, n: &str, e: &str, t: f64, c: Score, a: Score, star_c: bool| {
        let mark = |s: bool| if s { "*" } else { " " };
        println!(
            "   {:<10} {:>9} {:>9} {:>8.3}s | {:.3e}{} ({:+.2e}) | {:.3e}{} ({:+.2e}) | {:>5}",
            name,
            n,
            e,
            t,
            c.error,
            mark(star_c),
            c.signed,
            a.error,
            mark(!star_c),
            a.signed,
            c.dark
        );
    };
    row("wavefront", "-", "-", t_first, wf_centre, wf_average, false);

    let target = wf_average.error;
    let mut runs: Vec<Run> = Vec::new();
    let mut spent = 0.0;
    for k in FIRST_LOG2..=LAST_LOG2 {
        let count = 1usize << k;
        let t = Instant::now();
        let (volume, summary) =
            simulate_photons(&scene.lights[0], &medium, count, 1, &Options::default())
                .expect("the photon simulation runs");
        let time = t.elapsed().as_secs_f64();
        spent += time;
        let run = Run {
            count,
            entered: summary.emitted,
            time,
            average: score(&volume.fluence, &average, &scored),
            centre: score(&volume.fluence, &centre, &scored),
        };
        row(
            "photons",
            &format!("2^{k}"),
            &run.entered.to_string(),
            run.time,
            run.centre,
            run.average,
            false,
        );
        let done = run.average.error <= target;
        runs.push(run);
        if done || spent + 2.1 * time > PHOTON_CAP_S {
            break;
        }
    }
    println!(
        "   (* = the score used: each method against what it estimates; dark = cell-channels \
         at 0; times of single runs, the ratio uses the side-by-side ones below)"
    );
    if wf_centre.dark > 0 {
        println!(
            "   NOTE: the wavefront left {} cell-channels unreached (counted with error 1)",
            wf_centre.dark
        );
    }

    // Timings drift on a shared machine: the ratio takes the wavefront and
    // a fixed photon run timed in alternation, three times.
    let side = runs.last().map_or(1, |r| r.count).min(1 << SIDE_LOG2);
    let (mut t_wave, mut t_side) = (Vec::new(), Vec::new());
    for _ in 0..3 {
        t_wave.push(time_wavefront(&scene, &medium).0);
        let t = Instant::now();
        simulate_photons(&scene.lights[0], &medium, side, 2, &Options::default())
            .expect("the photon simulation runs");
        t_side.push(t.elapsed().as_secs_f64());
    }
    let t_wf = median(&t_wave);
    let cost = median(&t_side) / side as f64;
    let list = |v: &[f64]| {
        v.iter()
            .map(|t| format!("{t:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    println!(
        "   side by side: wavefront {} s (median {t_wf:.3} s); photons 2^{} {} s \
         (median: {cost:.3e} s/photon)",
        list(&t_wave),
        side.trailing_zeros(),
        list(&t_side)
    );

    let points: Vec<(u64, f64)> = runs
        .iter()
        .map(|r| (r.count as u64, r.average.error))
        .collect();
    let last_log2 = runs.last().map_or(0, |r| r.count.trailing_zeros());
    let eq = equal_error(&points, target);
    let t_eq = eq.count * cost;
    println!(
        "   photons at the wavefront's error {target:.3e}: N = {:.3e}, N * cost = {} ({})",
        eq.count,
        secs(t_eq),
        equal::describe(&eq, last_log2)
    );
    println!("   RATIO photons / wavefront: {:.1}x", t_eq / t_wf);
    let alt = equal_error(&points, wf_average.error);
    println!(
        "   both against cell averages (target {:.3e}): N = {:.3e}, {}, ratio {:.1}x",
        wf_average.error,
        alt.count,
        secs(alt.count * cost),
        alt.count * cost / t_wf
    );
    if matches!(eq.reach, Reach::Fitted { .. }) {
        let last = runs.last().expect("at least one photon run");
        let n = last.count as f64 * (last.average.error / target).powi(2);
        println!(
            "   with 1/sqrt(N) from the last run instead (independent photons; not what the \
             stratified draws show): N = {n:.3e}, {}, ratio {:.0}x",
            secs(n * cost),
            n * cost / t_wf
        );
    }
    Outcome {
        name: case.name,
        time: t_wf,
        error: target,
        photons: eq,
        photon_time: t_eq,
    }
}

fn main() {
    let start = Instant::now();
    println!(
        "Time to equal irradiance error: wavefront (simulate_light) vs photons (simulate_photons)"
    );
    println!(
        "64^3 grid on [-1, 1]^3, default Options (RK4, step 0.5 voxel), {} threads; \
         error = mean |estimate / exact - 1|",
        rayon::current_num_threads()
    );
    let results: Vec<Outcome> = CASES.iter().map(run_case).collect();
    println!();
    println!("== Summary (goal: ratio >= 20x) ==");
    println!(
        "   {:<10} {:>10} {:>10} {:>12} {:>12} {:>9}  how",
        "scene", "wf error", "wf time", "photons N", "photon time", "ratio"
    );
    for o in &results {
        let how = match o.photons.reach {
            Reach::Measured { .. } | Reach::AtMost => "measured",
            Reach::Fitted { .. } | Reach::Floored { .. } => "extrapolated",
            Reach::Never { .. } | Reach::BelowFloor { .. } => "not reached",
        };
        println!(
            "   {:<10} {:>10.3e} {:>9.3}s {:>12.3e} {:>12} {:>8.1}x  {how}",
            o.name,
            o.error,
            o.time,
            o.photons.count,
            secs(o.photon_time),
            o.photon_time / o.time
        );
    }
    println!("   total run time {:.0} s", start.elapsed().as_secs_f64());
}
