//! Time to equal irradiance error, wavefront vs an independent photon
//! tracer (issue 16): `cargo bench --bench equal_error_independent` (a
//! plain `main`; under 10 minutes on the 2-core development VM).
//!
//! The photons are `eikon_testkit::photon_ref`, a small tracer that shares
//! no code with `eikon_wavefront` (not its photons, not its deposit) nor
//! with `eikon_grid`'s rays, regions and fields. Its photons are drawn
//! independently (no stratification), so its error falls as `1/sqrt(N)`.
//!
//! # Scenes
//! * `vacuum`: the point-light scene of `benches/equal_error.rs` (64^3 on
//!   [-1, 1]^3, index 1, 1 W per channel at (0.137, -0.211, 0.073)). Exact
//!   answer `P / (4 pi r^2)`; error = mean over cells more than 3 voxels
//!   from the light and over channels of `|estimate / exact - 1|`, both
//!   methods against the exact cell average (6^3-point Gauss-Legendre), as
//!   `equal_error.rs` scores them (both estimate a cell average).
//! * `glass`: `configs/glass-sphere.toml` at 64^3 with sharp interfaces
//!   (n = 1.5 sphere at (0, 0.15, 0), radius 0.45, extinction
//!   [0.05, 0.03, 0.03], directional light [0.2, -1, 0.1] of irradiance 1).
//!   No analytic truth: the reference is the mean of two independent
//!   tracer runs of 2^24 photons each (seeds 1001 and 1002), whose
//!   disagreement states its own noise.
//!   The wavefront traces the Fresnel-reflected light too
//!   (`Options::reflections`).
//! * `glass, no reflected light`: the same, but the reference and the
//!   sweep drop a photon where it is reflected (seeds 2001 and 2002), and
//!   the wavefront runs with its default: its Fresnel reflection leaves the
//!   beam, not traced. Error = mean over lit cells
//!   (reference above 1% of its maximum, channel mean), away from the
//!   sphere's surface (cell centre more than 1 voxel from it) and from the
//!   grid's boundary, and over channels, of `|estimate / reference - 1|`.
//!
//! # Ratio
//! The wavefront's time is the median of 3 runs (medium and regions built
//! beforehand). The photon count `N*` at the wavefront's error is
//! interpolated in log-log between the sweep's runs around it, or
//! extrapolated over its last three runs (the output says which): in
//! vacuum by a fit `a N^b`; for the glass sphere, whose reference is the
//! tracer's own 2^25 photons, by the two noises' model
//! `error^2 = a (1/N + 1/2^25)` (`equal::equal_error_against_photons`:
//! near the reference's noise a power law falls too slowly and
//! undercounts; the output checks the model against the reference seeds'
//! disagreement). The glass sweeps go on to 2^26 photons where each run
//! stays within a minute, so that they usually reach the wavefront's error.
//! `N*`'s time is `N*` times the least cost per photon of the runs of
//! 2^20 photons and more.
//!
//! `EQ_DUMP=DIR` writes the glass scenes' reference, the first reference
//! run and the wavefront's fluence there as raw little-endian `f64`
//! (`(64, 64, 64, 3)`, standard order; `ref-SEED.f64`, `refa-SEED.f64`,
//! `wf-SEED.f64`), for a look at where they differ. `EQ_PATCH=VOXELS` sets
//! the glass scenes' emitted patch size (`Options::patch_size`, the
//! default's otherwise), to weigh the wavefront's sampling against its
//! time.

use eikon_grid::{Medium, Regions, Scene};
use eikon_testkit::photon_ref::{self, Grid, Light, Sphere};
use eikon_wavefront::{simulate_light_in, Options};
use glam::DVec3;
use ndarray::{Array3, Array4};
use std::f64::consts::PI;
use std::time::Instant;

#[path = "support/equal.rs"]
mod equal;
use equal::{median, Score, GL6};

const FIRST_LOG2: u32 = 14;
/// The sweep's last count: 2^22 in vacuum, whose truth is exact; 2^26 for
/// the glass sphere, whose reference carries its own noise, so that the
/// sweep reaches the wavefront's error where [`RUN_CAP_S`] allows rather
/// than extrapolate to it (`EQ_LAST_LOG2` overrides both, for a quick
/// look).
fn last_log2(noisy_reference: bool) -> u32 {
    env_u32("EQ_LAST_LOG2", if noisy_reference { 26 } else { 22 })
}
/// Photons per reference run of the glass sphere (two runs), 2^24
/// (`EQ_REF_LOG2` overrides).
fn ref_log2() -> u32 {
    env_u32("EQ_REF_LOG2", 24)
}

fn env_u32(name: &str, default: u32) -> u32 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}
/// The glass scenes' emitted patch size, voxels: `EQ_PATCH`, else the
/// default's at sharp interfaces. An unreadable value is said and not used.
fn patch_size() -> f64 {
    let default = Options::default().emitted_size(true);
    match std::env::var("EQ_PATCH") {
        Err(_) => default,
        Ok(v) => match v.parse::<f64>() {
            Ok(x) if x.is_finite() && x > 0.0 => x,
            _ => {
                println!("EQ_PATCH={v:?} is not a positive size in voxels: {default} used");
                default
            }
        },
    }
}

/// No photon run predicted (twice the last) beyond this, s.
const RUN_CAP_S: f64 = 60.0;

const LIGHT: DVec3 = DVec3::new(0.137, -0.211, 0.073);

const VACUUM: &str = "[grid]\nresolution = 64\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
    [ambient]\nindex = 1.0\nextinction = [0, 0, 0]\n\
    [[light]]\ntype = \"point\"\nposition = [0.137, -0.211, 0.073]\npower = [1, 1, 1]\n";

const GLASS: &str = "[grid]\nresolution = 64\nmin = [-1.0, -1.0, -1.0]\nmax = [1.0, 1.0, 1.0]\n\
    smoothing = 0.75\n\
    [ambient]\nindex = 1.0\n\
    [[object]]\nname = \"glass sphere\"\n\
    shape = { type = \"sphere\", center = [0.0, 0.15, 0.0], radius = 0.45 }\n\
    index = 1.5\nextinction = [0.05, 0.03, 0.03]\npriority = 1\n\
    [[light]]\ntype = \"directional\"\ndirection = [0.2, -1.0, 0.1]\npower = [1.0, 1.0, 1.0]\n";

const SPHERE: Sphere = Sphere {
    centre: DVec3::new(0.0, 0.15, 0.0),
    radius: 0.45,
    index: 1.5,
    extinction: [0.05, 0.03, 0.03],
};

fn grid() -> Grid {
    Grid {
        min: DVec3::splat(-1.0),
        max: DVec3::splat(1.0),
        dims: [64; 3],
    }
}

/// [`equal::score`] of `est` against `truth` over `mask`.
fn score(est: &Array4<f64>, truth: &Array4<f64>, mask: &Array3<bool>) -> Score {
    equal::score(mask, |ix| est[ix], |ix| truth[ix])
}

/// The wavefront three times: median time and the volume.
fn wavefront(
    scene: &Scene,
    medium: &Medium,
    regions: Option<&Regions>,
    opts: &Options,
) -> (f64, Array4<f64>, String) {
    let mut times = Vec::new();
    let mut out = None;
    for _ in 0..3 {
        let t = Instant::now();
        let (volume, summary) =
            simulate_light_in(&scene.lights[0], medium, regions, opts, &|_, _| {})
                .expect("the wavefront simulation runs");
        times.push(t.elapsed().as_secs_f64());
        out = Some((volume, summary));
    }
    let (volume, s) = out.expect("three runs");
    let account = format!(
        "entered {:.4} W, absorbed {:.4}, exited {:.4}, reflected {:.4}, culled {:.4}, trapped {:.4} (channel 0)",
        s.entered[0],
        s.absorbed_power[0],
        s.exited_power[0],
        s.reflected_power[0],
        s.culled_power[0],
        s.trapped_power[0]
    );
    println!(
        "   wavefront times {:.3}, {:.3}, {:.3} s",
        times[0], times[1], times[2]
    );
    (median(&times), volume.fluence.mapv(f64::from), account)
}

struct Run {
    count: u64,
    time: f64,
    error: f64,
}

/// The photon sweep against `truth` over `mask`, seeds from `seed`.
fn sweep(
    scene: &photon_ref::Scene,
    truth: &Array4<f64>,
    mask: &Array3<bool>,
    target: f64,
    seed: u64,
    last: u32,
) -> Vec<Run> {
    let mut runs: Vec<Run> = Vec::new();
    for k in FIRST_LOG2..=last {
        if runs.last().is_some_and(|r| 2.1 * r.time > RUN_CAP_S) {
            println!("   (stopped: 2^{k} would take over {RUN_CAP_S} s)");
            break;
        }
        let count = 1u64 << k;
        let t = Instant::now();
        let out = photon_ref::simulate(scene, count, seed + u64::from(k));
        let time = t.elapsed().as_secs_f64();
        let s = score(&out.fluence, truth, mask);
        println!(
            "   photons 2^{k:<2} {time:>8.3} s  error {:.3e} (signed {:+.2e}, dark {})",
            s.error, s.signed, s.dark
        );
        runs.push(Run {
            count,
            time,
            error: s.error,
        });
        if s.error <= target {
            break;
        }
    }
    runs
}

struct Outcome {
    name: &'static str,
    error: f64,
    time: f64,
    count: f64,
    photon_time: f64,
    how: String,
}

/// Where the sweep `runs` reaches the wavefront's `error`; `reference`:
/// the photons of the tracer's own reference it was scored against, if it
/// has no exact truth ([`equal::equal_error_against_photons`]).
fn conclude(
    name: &'static str,
    error: f64,
    time: f64,
    runs: &[Run],
    reference: Option<f64>,
) -> Outcome {
    let points: Vec<(u64, f64)> = runs.iter().map(|r| (r.count, r.error)).collect();
    let last = runs.last().expect("at least one photon run");
    let eq = match reference {
        Some(n) => equal::equal_error_against_photons(&points, error, n),
        None => equal::equal_error(&points, error),
    };
    let (count, how) = (eq.count, equal::describe(&eq, last.count.trailing_zeros()));
    // The photons' cost per photon: the least of the runs of 2^20 and up
    // (their fixed costs spent; a run slowed by anything else on the
    // machine would only flatter the wavefront).
    let cost = runs
        .iter()
        .filter(|r| r.count >= 1 << 20)
        .map(|r| r.time / r.count as f64)
        .fold(last.time / last.count as f64, f64::min);
    let photon_time = count * cost;
    println!(
        "   photons at the wavefront's error {error:.3e}: N = {count:.3e} ({how}); \
         cost {cost:.3e} s/photon (the least of the runs from 2^20) -> {photon_time:.1} s; \
         RATIO {:.1}x",
        photon_time / time
    );
    Outcome {
        name,
        error,
        time,
        count,
        photon_time,
        how,
    }
}

fn vacuum() -> Outcome {
    println!("\n== vacuum: 1 W point light at {LIGHT} in [-1, 1]^3, 64^3, index 1 ==");
    let scene = Scene::parse(VACUUM, "vacuum").expect("the scene parses");
    let medium = Medium::build(&scene).expect("the medium builds");
    let (t_wf, wf, account) = wavefront(&scene, &medium, None, &Options::default());
    println!("   wavefront account: {account}");
    let g = grid();
    let h = g.cell().x;
    let exact = |x: DVec3| 1.0 / (4.0 * PI * (x - LIGHT).length_squared());
    let average = Array4::from_shape_fn((64, 64, 64, 3), |(i, j, k, _)| {
        let c = g.centre(i, j, k);
        let mut s = 0.0;
        for (a, wa) in GL6 {
            for (b, wb) in GL6 {
                for (d, wd) in GL6 {
                    s += wa * wb * wd * exact(c + 0.5 * h * DVec3::new(a, b, d));
                }
            }
        }
        s / 8.0
    });
    let centre = Array4::from_shape_fn((64, 64, 64, 3), |(i, j, k, _)| exact(g.centre(i, j, k)));
    let mask = Array3::from_shape_fn((64, 64, 64), |(i, j, k)| {
        (g.centre(i, j, k) - LIGHT).length() > 3.0 * h
    });
    let wa = score(&wf, &average, &mask);
    let wc = score(&wf, &centre, &mask);
    println!(
        "   {} cells scored; wavefront {t_wf:.3} s, error vs cell average {:.3e} (signed {:+.2e}, dark {}), \
         vs centre {:.3e}",
        mask.iter().filter(|&&m| m).count(),
        wa.error,
        wa.signed,
        wa.dark,
        wc.error
    );
    let scene_ref = photon_ref::Scene {
        grid: g,
        sphere: None,
        light: Light::Point {
            position: LIGHT,
            power: [1.0; 3],
        },
        reflections: true,
    };
    let runs = sweep(&scene_ref, &average, &mask, wa.error, 1, last_log2(false));
    conclude("vacuum", wa.error, t_wf, &runs, None)
}

fn glass() -> Vec<Outcome> {
    let patch = patch_size();
    println!(
        "\n== glass: configs/glass-sphere.toml at 64^3, sharp interfaces, directional light; \
         emitted patches {patch} voxel ==",
    );
    let scene = Scene::parse(GLASS, "glass").expect("the scene parses");
    assert_eq!(scene.grid.interfaces, eikon_grid::Interfaces::Sharp);
    let medium = Medium::build(&scene).expect("the medium builds");
    let regions = Regions::new(&scene).clear_of(&medium);
    let g = grid();
    let h = g.cell().x;
    let inside = |x: DVec3| (x - SPHERE.centre).length() < SPHERE.radius;
    let ref_log2 = ref_log2();
    let mut mask: Option<Array3<bool>> = None;
    let mut references: Vec<Array4<f64>> = Vec::new();
    let mut outcomes = Vec::new();
    // First the physics (reflected photons traced), then the rule the
    // wavefront follows (Fresnel's reflected part leaves the beam, not
    // traced): reflected photons dropped where they reflect.
    for (name, reflections, seed) in [
        ("glass", true, 1000),
        ("glass, no reflected light", false, 2000),
    ] {
        println!(
            "\n-- {name}: reference with reflected photons {} --",
            if reflections { "traced" } else { "dropped" }
        );
        let opts = Options {
            reflections,
            patch_size: Some(patch),
            ..Options::default()
        };
        let (t_wf, wf, account) = wavefront(&scene, &medium, Some(&regions), &opts);
        println!("   wavefront (reflections traced: {reflections}) account: {account}");
        let scene_ref = photon_ref::Scene {
            grid: g,
            sphere: Some(SPHERE),
            light: Light::Directional {
                direction: DVec3::new(0.2, -1.0, 0.1),
                irradiance: [1.0; 3],
            },
            reflections,
        };
        let t = Instant::now();
        let a = photon_ref::simulate(&scene_ref, 1 << ref_log2, seed + 1);
        let b = photon_ref::simulate(&scene_ref, 1 << ref_log2, seed + 2);
        let t_ref = t.elapsed().as_secs_f64();
        let acc = a.account;
        println!(
            "   reference: 2 x 2^{ref_log2} photons (seeds {}, {}) in {t_ref:.1} s; account \
             (channel 0, first seed): entered {:.4} W, absorbed {:.4}, left {:.4}, dropped {:.4}, \
             capped {:.1e}; imbalance {:.1e}; {:.3} interactions per entered photon, \
             {:.1}% of them reflections, most {}",
            seed + 1,
            seed + 2,
            acc.entered[0],
            acc.absorbed[0],
            acc.left[0],
            acc.dropped[0],
            acc.capped[0],
            acc.imbalance(),
            acc.interactions as f64 / acc.entered_photons as f64,
            100.0 * acc.reflections as f64 / acc.interactions.max(1) as f64,
            acc.most_interactions
        );
        let reference = (&a.fluence + &b.fluence) * 0.5;
        // The scored cells, from the physical reference, the same for both.
        let mask = mask.get_or_insert_with(|| {
            let lum = reference.sum_axis(ndarray::Axis(3)) / 3.0;
            let max = lum.fold(0.0f64, |m, &x| m.max(x));
            Array3::from_shape_fn((64, 64, 64), |(i, j, k)| {
                let edge = [i, j, k].iter().any(|&q| q == 0 || q == 63);
                let x = g.centre(i, j, k);
                let near = ((x - SPHERE.centre).length() - SPHERE.radius).abs() <= h;
                !edge && !near && lum[[i, j, k]] > 0.01 * max
            })
        });
        let cells = mask.iter().filter(|&&m| m).count();
        let between = score(&a.fluence, &b.fluence, mask);
        // Each run has about between / sqrt(2) mean relative error, their
        // mean half of `between`.
        println!(
            "   {cells} lit cells scored; reference noise: the two seeds differ by {:.3e} \
             (signed {:+.1e}), so the reference (their mean) carries about {:.1e}",
            between.error,
            between.signed,
            0.5 * between.error
        );
        if let Some(full) = references.first() {
            let d = score(&reference, full, mask);
            println!(
                "   this reference vs the physical one: {:.3e} (signed {:+.2e})",
                d.error, d.signed
            );
        }
        if let Ok(dir) = std::env::var("EQ_DUMP") {
            let raw = |a: &Array4<f64>, name: &str| {
                let bytes: Vec<u8> = a.iter().flat_map(|x| x.to_le_bytes()).collect();
                std::fs::write(format!("{dir}/{name}-{seed}.f64"), bytes).expect("dump");
            };
            raw(&reference, "ref");
            raw(&wf, "wf");
            raw(&a.fluence, "refa");
        }
        let w = score(&wf, &reference, mask);
        let part = |want_inside: bool| {
            let m = Array3::from_shape_fn(mask.dim(), |(i, j, k)| {
                mask[[i, j, k]] && inside(g.centre(i, j, k)) == want_inside
            });
            (m.iter().filter(|&&x| x).count(), score(&wf, &reference, &m))
        };
        let ((n_in, s_in), (n_out, s_out)) = (part(true), part(false));
        println!(
            "   wavefront {t_wf:.3} s, error {:.3e} (signed {:+.2e}, dark {}); inside the sphere \
             ({n_in} cells) {:.3e} (signed {:+.2e}), outside ({n_out}) {:.3e} (signed {:+.2e})",
            w.error, w.signed, w.dark, s_in.error, s_in.signed, s_out.error, s_out.signed
        );
        let runs = sweep(
            &scene_ref,
            &reference,
            mask,
            w.error,
            seed + 100,
            last_log2(true),
        );
        // The noise model's check: what it says two reference runs differ
        // by, beside what they did.
        let photons = 2.0 * (1u64 << ref_log2) as f64;
        let points: Vec<(u64, f64)> = runs.iter().map(|r| (r.count, r.error)).collect();
        let a = equal::photon_noise(&points, photons);
        println!(
            "   photon noise model error^2 = a (1/N + 1/{photons:.3e}), a = {a:.3e} from the last \
             runs: two reference runs would differ by {:.3e} (they differ by {:.3e}); the \
             reference alone carries {:.3e}",
            (a * 2.0 / (1u64 << ref_log2) as f64).sqrt(),
            between.error,
            (a / photons).sqrt()
        );
        outcomes.push(conclude(name, w.error, t_wf, &runs, Some(photons)));
        references.push(reference);
    }
    outcomes
}

fn main() {
    let start = Instant::now();
    println!(
        "Time to equal irradiance error: wavefront (simulate_light_in) vs an independent photon \
         tracer (eikon_testkit::photon_ref); {} threads",
        rayon::current_num_threads()
    );
    let mut results = vec![vacuum()];
    results.extend(glass());
    println!("\n== Summary (goal: ratio >= 20x) ==");
    println!(
        "| scene | wavefront error | wavefront time | photons at that error | photon time | ratio | how |"
    );
    println!("|---|---|---|---|---|---|---|");
    for o in &results {
        println!(
            "| {} | {:.2e} | {:.2} s | {:.2e} | {:.1} s | **{:.1}x** | {} |",
            o.name,
            o.error,
            o.time,
            o.count,
            o.photon_time,
            o.photon_time / o.time,
            o.how
        );
    }
    println!("total run time {:.0} s", start.elapsed().as_secs_f64());
}
