//! Physics tests of the light simulation (adaptive wavefront tracing)
//! against analytic optics.

use eikon_grid::{Medium, Scene};
use eikon_testkit::scenes::{glass_sphere, medium};
use eikon_wavefront::{simulate_light, LightVolume, Options, Summary};
use glam::DVec3;
use std::f64::consts::PI;

fn run(scene: &Scene, m: &Medium, light: usize) -> (LightVolume, Summary) {
    simulate_light(&scene.lights[light], m, &Options::default(), &|_, _| {}).unwrap()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// A spot light's cone: on a plane below it, a cell is lit (at least half
/// the point light's `P / (4 pi r^2)`) when its centre is inside the cone.
/// Cells may disagree only within one cell diagonal of the cone's surface:
/// the edge is resolved by the emitted patches (a point light's are 5.6
/// degrees wide, about 2 cells here), and the deposit rule fills cells under
/// a patch's corners up to a cell beyond the edge.
#[test]
fn a_spot_light_lights_its_cone() {
    let p = DVec3::new(0.01, 0.9, -0.02);
    let angle: f64 = 20.0;
    let (scene, m) = medium(&format!(
        "[grid]\nresolution = 64\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
         [[light]]\ntype = \"spot\"\nposition = [{}, {}, {}]\ndirection = [0, -1, 0]\n\
         angle = {angle}\npower = [1, 1, 1]\n",
        p.x, p.y, p.z
    ));
    let (vol, _) = run(&scene, &m, 0);
    let g = &m.geometry;
    let h = g.voxel_size();
    let j = 16; // y = -0.484
    let (mut lit, mut inside, mut wrong) = (0, 0, 0);
    let mut farthest: f64 = 0.0;
    for i in 0..64 {
        for k in 0..64 {
            let c = g.voxel_center(i, j, k);
            let d = c - p;
            let theta = d.normalize().dot(-DVec3::Y).acos().to_degrees();
            let want = 1.0 / (4.0 * PI * d.length_squared());
            let on = vol.fluence[[i, j, k, 0]] as f64 > 0.5 * want;
            let cone = theta < angle;
            lit += usize::from(on);
            inside += usize::from(cone);
            if on != cone {
                wrong += 1;
                // Distance of the cell centre from the cone's surface.
                let off = d.length() * (theta - angle).abs().to_radians().sin();
                farthest = farthest.max(off / h);
            }
        }
    }
    println!(
        "spot cone: {lit} cells lit, {inside} inside the cone, {wrong} differ, the farthest {farthest:.2} cells from the edge"
    );
    assert!(
        farthest <= 2f64.sqrt(),
        "a cell {farthest:.2} cells from the cone's edge is wrong"
    );
}

/// The estimate behind `simulate`'s time left: in a homogeneous medium
/// the wavefront crosses the box in straight lines, so the steps it takes
/// are the estimate's, for a plane wave (oblique) and a point light inside
/// and outside the box, at the medium's index n = 1.33.
#[test]
fn crossing_steps_match_a_straight_crossing() {
    for light in [
        "type = \"directional\"\ndirection = [1, 0.45, -0.3]",
        "type = \"point\"\nposition = [0.3, -0.2, 0.1]",
        "type = \"point\"\nposition = [-2.5, 0.1, 0.2]",
    ] {
        let (scene, m) = medium(&format!(
            "[grid]\nresolution = 24\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
             [ambient]\nindex = 1.33\n[[light]]\n{light}\npower = [1, 1, 1]\n"
        ));
        let opts = Options::default();
        let want = eikon_wavefront::crossing_steps(&scene.lights[0], &m, &opts);
        let (_, s) = run(&scene, &m, 0);
        println!("{light:?}: {} steps, estimate {want}", s.steps);
        let diff = (s.steps as f64 - want as f64).abs();
        assert!(diff <= 0.05 * want as f64 + 2.0, "{} vs {want}", s.steps);
    }
}

#[test]
fn energy_is_accounted_for() {
    let (scene, m) = medium(&glass_sphere(64, ""));
    for l in 0..scene.lights.len() {
        let (_, s) = run(&scene, &m, l);
        let imbalance = s.energy_imbalance();
        println!(
            "light {l}: entered {:.4?} absorbed {:.4?} exited {:.4?} culled {:.4?}; imbalance {imbalance:.2e}; {} steps, peak {} patches, ended: {} exited, {} absorbed, {} caustic, {} at the step limit",
            s.entered, s.absorbed_power, s.exited_power, s.culled_power, s.steps, s.peak_patches, s.exited, s.absorbed, s.caustic, s.step_limit
        );
        assert!(imbalance <= 0.005, "light {l}: imbalance {imbalance}");
        // The glass absorbs blue most (extinction 0.3, 0.6, 0.9).
        let frac = |c: usize| s.absorbed_power[c] / s.entered[c];
        assert!(frac(2) > frac(1) && frac(1) > frac(0), "absorbed fractions");
        assert!(s.entered.iter().all(|&e| e > 0.0));
    }
}

#[test]
fn volumes_are_identical_whatever_the_thread_count() {
    let (scene, m) = medium(&glass_sphere(64, ""));
    let with = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run(&scene, &m, 0))
    };
    let (a, sa) = with(1);
    let (b, sb) = with(2);
    assert_eq!(a.fluence, b.fluence);
    assert_eq!(a.flux, b.flux);
    assert_eq!(sa, sb);
}

#[test]
fn the_light_reads_nothing_only_renderers_read() {
    // `eikon simulate` releases albedo, g and emission before it simulates:
    // the volumes must be the same bits as with them held. A scene whose
    // glass scatters and emits, so that they are not all zero.
    let text = glass_sphere(32, "").replace(
        "albedo = [0.5, 0.5, 0.5]",
        "albedo = [0.5, 0.5, 0.5]\nemission = [0.2, 0.1, 0.0]\ng = 0.4",
    );
    assert_ne!(text, glass_sphere(32, ""), "the scene was changed");
    let (scene, m) = medium(&text);
    assert!(m.emission.iter().any(|&e| e > 0.0) && m.albedo.iter().any(|&a| a > 0.0));
    let mut light_only = m.clone();
    light_only.release_render_properties();
    assert!(m.has_render_properties() && !light_only.has_render_properties());
    assert!(
        light_only.albedo.is_empty() && light_only.g.is_empty() && light_only.emission.is_empty()
    );
    for l in 0..scene.lights.len() {
        let (a, sa) = run(&scene, &m, l);
        let (b, sb) = run(&scene, &light_only, l);
        assert_eq!(a.fluence, b.fluence, "light {l}");
        assert_eq!(a.flux, b.flux, "light {l}");
        assert_eq!(sa, sb, "light {l}");
    }
}

#[test]
fn bad_settings_and_scenes_are_refused() {
    let (scene, m) = medium(&glass_sphere(64, ""));
    for (opts, what) in [
        (
            Options {
                threshold: 0.0,
                ..Options::default()
            },
            "threshold",
        ),
        (
            Options {
                threshold: -1.0,
                ..Options::default()
            },
            "threshold",
        ),
        (
            Options {
                step: 0.0,
                ..Options::default()
            },
            "step",
        ),
        (
            Options {
                integrator: eikon_grid::Integrator::DormandPrince,
                ..Options::default()
            },
            "integrator",
        ),
    ] {
        let e = simulate_light(&scene.lights[0], &m, &opts, &|_, _| {})
            .unwrap_err()
            .to_string();
        assert!(e.starts_with(what), "{e}");
    }
    let (dark, dm) = medium("[grid]\nresolution = 8\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n");
    let e = eikon_wavefront::check_scene(&dark, &dm, &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("no [[light]]"), "{e}");
    let (buried, bm) = medium(
        "[grid]\nresolution = 8\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n\
         [[object]]\nshape = { type = \"sphere\", center = [0.5, 0.5, 0.5], radius = 0.3 }\nindex = 1.5\nextinction = [1e6, 1e6, 1e6]\n\
         [[light]]\ntype = \"point\"\nposition = [0.5, 0.5, 0.5]\npower = [1, 1, 1]\n",
    );
    let e = eikon_wavefront::check_scene(&buried, &bm, &Options::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("light[0].position") && e.contains("opaque"),
        "{e}"
    );
}

/// Trace a plane wave's patches (no tessellation) for `steps` equal-time
/// steps through the scene and measure each corner's optical path
/// independently: the sum over its steps of |dx| times n averaged by
/// Simpson's rule. Returns the largest spread between a patch's corners and
/// the largest distance from the elapsed time t, both in voxels, and how
/// many patches were bent away from the light's direction.
fn wavefront_drift(text: &str, length: f64, step: f64) -> (f64, f64, usize) {
    use eikon_grid::IndexField;
    use eikon_wavefront::{light, propagate, Patches};
    let (scene, m) = medium(text);
    let g = &m.geometry;
    let h = g.voxel_size();
    let field = propagate::Bounded::new(&m, 0);
    let empty = eikon_grid::EmptySpace::new(&m, 0);
    let mut p = Patches::default();
    light::emit(&scene.lights[0], g, &field, h, [1.0; 3], &mut p);
    let d0 = p.direction(0);
    let dt = step * h;
    let steps = (length / dt).round() as usize;
    let mut opl = vec![[0.0f64; 4]; p.len()];
    let mut losses = Vec::new();
    let step_of = propagate::Step {
        medium: &m,
        field: Some(&field),
        empty: &empty,
        integrator: eikon_grid::Integrator::Rk4,
        dt,
        interfaces: None,
        channel: 0,
        tally: None,
        group: None,
        sharp: None,
        run: propagate::Run::NONE,
    };
    for _ in 0..steps {
        let before: Vec<[DVec3; 4]> = (0..p.len()).map(|i| p.positions(i)).collect();
        propagate::propagate(&mut p, &step_of, &mut losses);
        for (i, (b, o)) in before.iter().zip(opl.iter_mut()).enumerate() {
            let a = p.positions(i);
            for c in 0..4 {
                let n = |x: DVec3| field.sample(x).0;
                let mean = (n(b[c]) + 4.0 * n((a[c] + b[c]) * 0.5) + n(a[c])) / 6.0;
                o[c] += mean * (a[c] - b[c]).length();
            }
        }
    }
    let t = steps as f64 * dt;
    let (mut spread, mut off, mut bent) = (0.0f64, 0.0f64, 0usize);
    for (i, o) in opl.iter().enumerate() {
        let lo = o.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = o.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        spread = spread.max(hi - lo);
        off = off.max((hi - t).abs().max((lo - t).abs()));
        if p.direction(i).dot(d0) < 0.99 {
            bent += 1;
        }
    }
    (spread / h, off / h, bent)
}

#[test]
fn particles_stay_on_one_wavefront() {
    // Corners move with the equal-time equations [Ihrke07 eqs 14-15] on
    // the shell |v| = n, so after time t every one has travelled optical path t,
    // however differently the medium bent them. What remains is the
    // stepping error: it must shrink with the step (here about 2x per
    // halving), and at the default half-voxel step stay within a
    // five-hundredth of a voxel in a smooth field (a Luneburg lens) and a
    // fiftieth across glass (a sharp interface smoothed over three voxels).
    let lens = "[grid]\nresolution = 64\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
        [[object]]\nshape = { type = \"sphere\", center = [0, 0, 0], radius = 0.8 }\nindex = { type = \"luneburg\" }\n\
        [[light]]\ntype = \"directional\"\ndirection = [0.1, 0.05, 1]\npower = [1, 1, 1]\n";
    let sphere = glass_sphere(64, "");
    for (name, text, length, bound) in [
        ("Luneburg lens", lens, 1.5625, 2e-3),
        ("glass sphere", sphere.as_str(), 2.5, 2e-2),
    ] {
        let (spread, off, bent) = wavefront_drift(text, length, 0.5);
        let (spread_half, off_half, _) = wavefront_drift(text, length, 0.25);
        println!(
            "wavefront, {name}: {bent} patches bent; step 0.5 voxel: corner spread {spread:.2e}, off t by {off:.2e} voxel; step 0.25: {spread_half:.2e}, {off_half:.2e}"
        );
        assert!(bent > 100, "{name}: the wave must be bent");
        assert!(
            spread < bound && off < bound,
            "{name}: spread {spread}, off {off} voxel"
        );
        assert!(
            off / off_half > 1.8,
            "{name}: drift does not shrink with the step: {off} then {off_half}"
        );
    }
}

#[test]
fn no_spikes_where_patches_graze_a_refracting_sphere() {
    // A weakly refracting, absorbing sphere lit from behind: grazing
    // patches fold in its smoothed interface band. Without the caustic
    // rule of `deposit::paper`, cells there held over 500 times the unrefracted
    // 1/r^2 irradiance (a speckled ring); refraction and absorption alone
    // stay within a small factor of it.
    let light = DVec3::new(0.4, 0.6, -2.5);
    let (scene, m) = medium(&format!(
        "[grid]\nresolution = 48\nmin = [-0.8, -0.8, -0.8]\nmax = [0.8, 0.8, 0.8]\n\
         [[object]]\nshape = {{ type = \"sphere\", center = [0, 0, 0], radius = 0.55 }}\n\
         index = 1.1\nextinction = [1.2, 2.2, 4.5]\nalbedo = [0.9, 0.75, 0.5]\n\
         [[light]]\ntype = \"point\"\nposition = [{}, {}, {}]\npower = [60, 60, 60]\n",
        light.x, light.y, light.z
    ));
    let (vol, _) = run(&scene, &m, 0);
    let g = &m.geometry;
    let mut ratios = Vec::new();
    for ((i, j, k), &e) in vol.fluence.slice(ndarray::s![.., .., .., 0]).indexed_iter() {
        let c = g.voxel_center(i, j, k);
        if c.length() < 0.62 {
            let free = 60.0 / (4.0 * PI * (c - light).length_squared());
            ratios.push(e as f64 / free);
        }
    }
    let max = ratios.iter().copied().fold(0.0, f64::max);
    let med = median(ratios);
    println!("sphere: irradiance over free 1/r^2: median {med:.2}, max {max:.1}");
    assert!(med > 0.5 && med < 1.0, "median {med}");
    assert!(max < 40.0, "a cell holds {max} times the free irradiance");
}

/// Straight runs through empty space ([`eikon_wavefront::propagate::Run`])
/// take several steps at once: the light volume must be what the steps
/// one at a time deposit. A plane wave (patches that keep their shape, so
/// every patch in empty space runs) past a smoothed glass ball that bends
/// part of it, each version stepped until every patch has left the grid;
/// no tessellation, so the patches are the same in both.
#[test]
fn runs_through_empty_space_deposit_what_their_steps_do() {
    // Runs save a quarter of the patch steps or more.
    runs_deposit_what_their_steps_do(BALL, "", 0.75);
}

/// The same through uniform absorbing space: an absorbing ambient medium
/// and ball, so that nothing is empty and every run loses `exp(-sigma l)`
/// along its way. Runs must still save a tenth of the patch steps (fewer
/// than in empty space: where it absorbs a run stops at the grid's faces
/// and near them takes single steps). The light volume and the absorbed
/// power must be what the steps one at a time give.
#[test]
fn runs_through_uniform_absorbing_space_deposit_what_their_steps_do() {
    let ambient = "[ambient]\nextinction = [0.6, 0.3, 0.1]\n";
    runs_deposit_what_their_steps_do(
        &format!("{ambient}{BALL}"),
        "extinction = [2.0, 1.0, 0.5]\n",
        0.9,
    );
}

/// A glass ball (radius 0.3, 40^3 over [-1, 1]^3) under a directional
/// light; the ball's material lines follow.
const BALL: &str = "[grid]\nresolution = 40\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
    [[light]]\ntype = \"directional\"\ndirection = [0.3, -1.0, 0.2]\npower = [1, 1, 1]\n\
    [[object]]\nshape = { type = \"sphere\", center = [0.1, 0, 0], radius = 0.3 }\nindex = 1.5\n";

/// Runs against steps in `scene` with the ball's `material`: runs must
/// take fewer than `saving` of the steps' patch steps.
fn runs_deposit_what_their_steps_do(scene: &str, material: &str, saving: f64) {
    use eikon_wavefront::deposit::Counters;
    use eikon_wavefront::{light, propagate, Patches};
    let (scene, m) = medium(&format!("{scene}{material}"));
    let g = &m.geometry;
    let h = g.voxel_size();
    let field = propagate::Bounded::new(&m, 0);
    let empty = eikon_grid::EmptySpace::new(&m, 0);
    let volume = |run: propagate::Run| {
        let tally = Counters::new(g, 1, [4.0; 3], 1e9);
        let mut p = Patches::default();
        light::emit(&scene.lights[0], g, &field, h, [1.0; 3], &mut p);
        let step_of = propagate::Step {
            medium: &m,
            field: Some(&field),
            empty: &empty,
            integrator: eikon_grid::Integrator::Rk4,
            dt: 0.5 * h,
            interfaces: None,
            channel: 0,
            tally: Some(&tally),
            group: None,
            sharp: None,
            run,
        };
        let (mut losses, mut calls) = (Vec::new(), 0);
        let inside = |p: &Patches, i: usize| p.positions(i).iter().any(|&x| g.contains(x));
        // Calls of the propagation per patch inside the grid.
        let mut patch_calls = 0;
        let mut absorbed = [0.0f64; 3];
        loop {
            let live = (0..p.len()).filter(|&i| inside(&p, i)).count();
            if live == 0 {
                break;
            }
            patch_calls += live;
            propagate::propagate(&mut p, &step_of, &mut losses);
            for l in &losses {
                for (a, x) in absorbed.iter_mut().zip(l.absorbed) {
                    *a += x;
                }
            }
            // What has left ends, as the tessellation analysis ends it.
            for i in 0..p.len() {
                if !inside(&p, i) {
                    p.flux[i] = [0.0; 3];
                }
            }
            calls += 1;
            assert!(calls < 2000);
        }
        (tally.into_volume(), patch_calls, absorbed)
    };
    let (one, calls_one, absorbed_one) = volume(propagate::Run::NONE);
    // Rules under which nothing is split or ended before it leaves the
    // grid: runs go as far as empty space and the grid let them.
    let rules = eikon_wavefront::refine::Rules {
        split_span: 4.0 * h,
        threshold: 0.0,
        max_patches: usize::MAX,
        max_depth: 0,
        cull_caustics: false,
        dim: 0.0,
        incident: eikon_wavefront::refine::Incident::Uniform([1.0; 3]),
        faint: 0.0,
        corner_rays: f64::INFINITY,
    };
    let (runs, calls_runs, absorbed_runs) = volume(propagate::Run {
        max_steps: propagate::MAX_RUN,
        rules: Some(rules),
        until: usize::MAX,
    });
    // The loss along a run is the product of its steps' (to rounding).
    for (a, b) in absorbed_runs.iter().zip(absorbed_one) {
        assert!(
            (a - b).abs() <= 1e-9 * b.max(1e-12),
            "absorbed {a} against {b}"
        );
    }
    println!("absorbed: {absorbed_runs:?} against {absorbed_one:?}");
    assert!(
        (calls_runs as f64) < saving * calls_one as f64,
        "{calls_runs} against {calls_one} patch steps"
    );
    let top = one.fluence.iter().fold(0.0f32, |a, &b| a.max(b)) as f64;
    let (mut worst, mut diff, mut lit) = (0.0f64, 0.0f64, 0);
    let (mut sum_one, mut sum_runs) = (0.0f64, 0.0f64);
    for (&a, &b) in one.fluence.iter().zip(runs.fluence.iter()) {
        let (a, b) = (a as f64, b as f64);
        worst = worst.max((a - b).abs());
        diff += (a - b).abs();
        sum_one += a;
        sum_runs += b;
        lit += (a > 0.01 * top) as usize;
    }
    let l1 = diff / sum_one;
    println!(
        "runs: {calls_runs} patch steps against {calls_one}; fluence: worst difference {:.2e} of the top, relative L1 {l1:.2e}, sums {sum_runs} against {sum_one}",
        worst / top
    );
    assert!(lit > 20_000, "{lit} lit cells");
    // A run's tube is deposited in one pass, its steps' one at a time:
    // the same flux times length, spread by sub-patch footprints that
    // differ only where a patch grows along the run (a run's patch is cut
    // into the sub-patches its end needs), so that what footprints at the
    // grid's faces leave outside differs a little too.
    assert!(
        (sum_runs / sum_one - 1.0).abs() < 1e-4,
        "{sum_runs} against {sum_one}"
    );
    assert!(l1 < 1e-3, "relative L1 {l1}");
    assert!(worst < 1e-2 * top, "{worst} of {top}");
}
