//! The track-length fluence deposit (the default light volume) against
//! physics: Fresnel at a slab, the energy account with light carried
//! through caustics, a plane wave's uniformity and direction, additivity of
//! crossing beams, the caustic under the [Ihrke07 fig 7] glass sphere
//! against an independent ray-optics integration (`support/exact_sphere.rs`,
//! which uses none of the engine's code), and a glass ball against the
//! photon baseline. Measured numbers are printed (`--nocapture`).

#[path = "support/exact_sphere.rs"]
mod exact_sphere;

use eikon_testkit::scenes::medium;
use eikon_wavefront::deposit::Counters;
use eikon_wavefront::photons::{simulate_photons, simulate_photons_in};
use eikon_wavefront::{
    simulate_light, simulate_light_in, DepositRule, LightVolume, Options, Summary,
};
use glam::DVec3;

fn wavefront(text: &str, opts: &Options) -> (eikon_grid::Medium, LightVolume, Summary) {
    let (scene, m) = medium(text);
    let (v, s) = simulate_light(&scene.lights[0], &m, opts, &|_, _| {}).unwrap();
    (m, v, s)
}

/// [Ihrke07 fig 7]: a clear glass sphere above the plane y = 0 (the
/// grid's floor) under a directional light.
fn fig7(resolution: usize) -> String {
    format!(
        r#"
[grid]
resolution = {resolution}
min = [-1.0, 0.0, -1.0]
max = [1.0, 1.2, 1.0]

[[object]]
shape = {{ type = "sphere", center = [0.0, 0.6, 0.0], radius = 0.5 }}
index = 1.5

[[light]]
type = "directional"
direction = [0.3, -1.0, 0.2]
power = [1, 1, 1]
"#
    )
}

/// Power landing on the floor inside the sphere's geometric shadow, read
/// from the light volume: `-F_y` of the bottom layer of cells times their
/// area, over the cells whose centre's column lies in the shadow.
fn shadow_power(m: &eikon_grid::Medium, v: &LightVolume) -> f64 {
    let s = exact_sphere::fig7();
    let g = &m.geometry;
    let sp = g.spacing();
    let mut p = 0.0;
    for i in 0..g.dims[0] {
        for k in 0..g.dims[2] {
            let c = g.voxel_center(i, 0, k);
            if exact_sphere::in_geometric_shadow(&s, c.x, c.z) {
                p += -(v.flux[0][[i, 0, k, 1]] as f64) * sp.x * sp.z;
            }
        }
    }
    p
}

#[test]
fn the_caustic_under_the_glass_sphere_carries_the_power_ray_optics_gives() {
    let exact = exact_sphere::transmitted_power_in_shadow(&exact_sphere::fig7(), true, 1000);
    println!("exact ray optics: {exact:.4} W in the shadow");
    let mut errors = Vec::new();
    for res in [64, 128] {
        let (m, v, s) = wavefront(&fig7(res), &Options::default());
        let p = shadow_power(&m, &v);
        println!(
            "{res}^3: fluence deposit {p:.4} W ({:+.1}%), {} patches culled at caustics",
            100.0 * (p / exact - 1.0),
            s.caustic,
        );
        assert_eq!(s.caustic, 0);
        // Only patches too faint to change any cell by 1e-4 of the
        // unobstructed light end early (`refine::Rules::faint`).
        assert!(
            s.culled_power[0] < 1e-4 * s.entered[0],
            "culled {:?} of {:?}",
            s.culled_power,
            s.entered
        );
        assert!(s.energy_imbalance() < 1e-9, "{}", s.energy_imbalance());
        errors.push((p / exact - 1.0).abs());
    }
    // The smoothed interface (sigma 0.75 voxel) widens the sphere by about
    // a voxel and under-reflects grazing light (the incidence is read
    // inside the band): the excess falls with the voxel size, about as h
    // (measured +19.0%, +10.0%, and +5.6% at 256^3 with `eikon simulate`).
    // The issue's goal is 10% at 128^3; it sits at that edge, and the
    // sharp-interfaces issue removes the cause.
    assert!(errors[1] < 0.105, "128^3: {:.4}", errors[1]);
    assert!(errors[1] < 0.6 * errors[0], "{errors:?}");
}

/// The paper's rule (`--deposit paper`, without Fresnel as in the paper)
/// is kept to reproduce its results, and they are wrong under the
/// [Ihrke07 fig 7] sphere: each cell keeps the brightest patch crossing it
/// [Ihrke07 sec 5.2.2], which under the sphere's focus counts light several
/// times over (at 128^3 it reads over ten times the exact power: `eikon
/// simulate --deposit paper --no-fresnel`), and patches are culled at the
/// caustic. (A test of its own, so that it runs beside the 128^3 run
/// above.)
#[test]
fn the_papers_rule_overcounts_the_caustic_under_the_glass_sphere() {
    let exact_clear = exact_sphere::transmitted_power_in_shadow(&exact_sphere::fig7(), false, 1000);
    let (mp, vp, sp) = wavefront(
        &fig7(64),
        &Options {
            deposit: DepositRule::Paper,
            fresnel: false,
            ..Options::default()
        },
    );
    let pp = shadow_power(&mp, &vp);
    println!(
        "64^3, paper's rule: {pp:.4} W against {exact_clear:.4} W without Fresnel, {:.4} W culled at caustics",
        sp.culled_power[0]
    );
    assert!(pp > 2.0 * exact_clear, "{pp} W");
    assert!(sp.caustic > 0 && sp.culled_power[0] > 0.0);
}

#[test]
fn a_plane_wave_in_vacuum_reads_its_irradiance_and_direction_in_every_cell() {
    let text = r#"
[grid]
resolution = 32
min = [-1, -1, -1]
max = [1, 1, 1]

[[light]]
type = "directional"
direction = [0.3, -1.0, 0.2]
power = [2, 1, 0.5]
"#;
    let (_, v, s) = wavefront(text, &Options::default());
    let d = DVec3::new(0.3, -1.0, 0.2).normalize();
    let (mut worst, mut worst_dir) = (0.0f64, 0.0f64);
    let mut sum = 0.0;
    let mut n = 0;
    // Cells two or more voxels inside the bounds (the wave enters the
    // corner cells through part of their faces).
    for i in 2..30 {
        for j in 2..30 {
            for k in 2..30 {
                for (c, e) in [2.0, 1.0, 0.5].into_iter().enumerate() {
                    let phi = v.fluence[[i, j, k, c]] as f64;
                    worst = worst.max((phi / e - 1.0).abs());
                    sum += (phi / e - 1.0).abs();
                    n += 1;
                }
                let f = DVec3::from_array([0, 1, 2].map(|a| v.flux[0][[i, j, k, a]] as f64));
                worst_dir = worst_dir.max(f.normalize().angle_between(d));
            }
        }
    }
    println!(
        "plane wave: mean |phi / E - 1| {:.4}, worst {worst:.4}; worst direction error {:.2e} rad",
        sum / n as f64,
        worst_dir
    );
    let mean = sum / n as f64;
    // What is left is how each patch's footprint is spread: a box across
    // the tube's main axis with the second moments of its cross-section
    // there, not the parallelogram itself, whose edges are sheared across
    // the two minor axes by a tilt about both (0.05% on average, 0.2% at
    // worst here; 0.3% and 0.7% when the footprint was the patch
    // projected straight onto the layer's plane; boxes cut once per step
    // and carried along lines left 0.4% and 1.6%, point sub-tracks half a
    // voxel apart 7% on average).
    assert!(mean < 0.005, "mean {mean}");
    assert!(worst < 0.02, "worst {worst}");
    assert!(worst_dir < 1e-4, "{worst_dir}");
    assert!(s.energy_imbalance() < 1e-12);
}

/// Plane waves in vacuum tilted within a plane of the grid's axes, at
/// 25, 40 and 45 degrees (and 60, whose tubes run along another axis):
/// every cell reads the irradiance to f32 rounding. A tube crosses the
/// layers of cells obliquely, and its footprint in a layer is its
/// cross-section there, the patch projected along the light onto the
/// layer's plane (`deposit::onto_layer`); projected straight onto the
/// plane, the footprints of neighbouring tubes did not add up evenly (at
/// 45 degrees 3.9% off on average, 8.9% at worst).
#[test]
fn a_tilted_plane_wave_reads_its_irradiance_in_every_cell() {
    for degrees in [25.0f64, 40.0, 45.0, 60.0] {
        let t = degrees.to_radians();
        let text = format!(
            "[grid]\nresolution = 32\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
             [[light]]\ntype = \"directional\"\ndirection = [{}, {}, 0.0]\npower = [1, 1, 1]\n",
            t.sin(),
            -t.cos()
        );
        let (_, v, _) = wavefront(&text, &Options::default());
        let (mut worst, mut sum, mut n) = (0.0f64, 0.0, 0);
        // Four voxels inside the bounds (the wave enters the cells near
        // them through part of their faces).
        for i in 4..28 {
            for j in 4..28 {
                for k in 4..28 {
                    let e = (v.fluence[[i, j, k, 0]] as f64 - 1.0).abs();
                    worst = worst.max(e);
                    sum += e;
                    n += 1;
                }
            }
        }
        println!(
            "plane wave at {degrees} degrees: mean |phi / E - 1| {:.2e}, worst {worst:.2e}",
            sum / n as f64
        );
        assert!(worst < 1e-4, "{degrees} degrees: worst {worst}");
    }
}

#[test]
fn crossing_beams_add_in_fluence_and_as_vectors() {
    // The deposit is linear: two beams deposited into one volume give the
    // sum of their volumes, fluence and flux vector.
    let g = eikon_grid::GridGeometry::new([8, 8, 8], DVec3::ZERO, DVec3::ONE);
    let beam = |c: &Counters, d: DVec3, e: f64| {
        // A lattice of chords across the box along d.
        for a in 0..40 {
            for b in 0..40 {
                let (u, w) = (
                    d.any_orthonormal_pair().0 * ((a as f64 + 0.5) / 20.0 - 1.0),
                    d.any_orthonormal_pair().1 * ((b as f64 + 0.5) / 20.0 - 1.0),
                );
                let o = DVec3::splat(0.5) + u + w - d * 2.0;
                c.chord(o, o + d * 4.0, &[e; 3], DVec3::ZERO, None);
            }
        }
    };
    let (d1, d2) = (
        DVec3::new(1.0, 0.2, 0.1).normalize(),
        DVec3::new(-0.3, 1.0, 0.4).normalize(),
    );
    let both = Counters::new(&g, 1, [1.0; 3], eikon_wavefront::UNITS_PER_CROSSING);
    beam(&both, d1, 1.0);
    beam(&both, d2, 0.5);
    let (a, b) = (
        Counters::new(&g, 1, [1.0; 3], eikon_wavefront::UNITS_PER_CROSSING),
        Counters::new(&g, 1, [1.0; 3], eikon_wavefront::UNITS_PER_CROSSING),
    );
    beam(&a, d1, 1.0);
    beam(&b, d2, 0.5);
    let (both, a, b) = (both.into_volume(), a.into_volume(), b.into_volume());
    let mut worst = 0.0f64;
    for (i, x) in both.fluence.iter().enumerate() {
        let sum = a.fluence.as_slice().unwrap()[i] + b.fluence.as_slice().unwrap()[i];
        worst = worst.max(((x - sum) / sum.max(1e-30)).abs() as f64);
    }
    for (i, x) in both.flux[0].iter().enumerate() {
        let sum = a.flux[0].as_slice().unwrap()[i] + b.flux[0].as_slice().unwrap()[i];
        let scale = both.fluence.as_slice().unwrap()[i].max(1e-30);
        worst = worst.max(((x - sum) / scale).abs() as f64);
    }
    println!("crossing beams: worst relative difference from the sum {worst:.2e}");
    assert!(worst < 1e-6, "{worst}");
    // Where both cross, |F| < phi: the mean cosine says the light mixes.
    let c = [4, 4, 4];
    let phi = both.fluence[[c[0], c[1], c[2], 0]] as f64;
    let f = DVec3::from_array([0, 1, 2].map(|k| both.flux[0][[c[0], c[1], c[2], k]] as f64));
    assert!(f.length() < 0.99 * phi, "{} vs {phi}", f.length());
}

#[test]
fn a_glass_ball_reads_what_the_photons_read_through_its_focus() {
    // A clear ball (n = 1.5) under a plane wave: inside it, at its focus
    // and behind it, the wavefront's fluence against the photon baseline's
    // (the same medium, the same Fresnel; two runs, whose difference
    // measures the photons' own noise).
    let text = r#"
[grid]
resolution = 48
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0.0, 0.35, 0.0], radius = 0.5 }
index = 1.5

[[light]]
type = "directional"
direction = [0.0, -1.0, 0.0]
power = [1, 1, 1]
"#;
    let (scene, m) = medium(text);
    let light = &scene.lights[0];
    let (wf, ws) = simulate_light(light, &m, &Options::default(), &|_, _| {}).unwrap();
    let count = 1_500_000;
    let (pa, psa) = simulate_photons(light, &m, count, 1, &Options::default()).unwrap();
    let (pb, _) = simulate_photons(light, &m, count, 2, &Options::default()).unwrap();
    println!(
        "ball: reflected wavefront {:.5} W, photons {:.5} W",
        ws.reflected_power[0], psa.reflected_power[0]
    );
    let mut rel = Vec::new();
    let mut noise = Vec::new();
    let (mut wmax, mut pmax) = ((0.0f32, 0usize), (0.0f32, 0usize));
    let [nx, ny, nz] = m.geometry.dims;
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                let w = wf.fluence[[i, j, k, 0]];
                let p = 0.5 * (pa.fluence[[i, j, k, 0]] + pb.fluence[[i, j, k, 0]]);
                if i == nx / 2 && k == nz / 2 {
                    if w > wmax.0 {
                        wmax = (w, j);
                    }
                    if p > pmax.0 {
                        pmax = (p, j);
                    }
                }
                if p > 0.01 {
                    rel.push(((w / p - 1.0) as f64).abs());
                    noise.push(
                        ((pa.fluence[[i, j, k, 0]] - pb.fluence[[i, j, k, 0]]) / (2.0 * p)).abs()
                            as f64,
                    );
                }
            }
        }
    }
    let pct = |v: &mut Vec<f64>, q: f64| {
        v.sort_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * q) as usize]
    };
    let (med, p95) = (pct(&mut rel, 0.5), pct(&mut rel, 0.95));
    let noise_med = pct(&mut noise, 0.5);
    println!(
        "ball vs {} photons: {} cells, median |w / p - 1| {med:.4}, 95th percentile {p95:.4}, photon noise median {noise_med:.4}; axial maximum: wavefront {:.2} at j = {}, photons {:.2} at j = {}",
        2 * count,
        rel.len(),
        wmax.0,
        wmax.1,
        pmax.0,
        pmax.1
    );
    assert!(med < 0.02, "median {med}");
    assert!(p95 < 0.10, "95th percentile {p95}");
    assert!((wmax.1 as i64 - pmax.1 as i64).abs() <= 1);
    assert!(
        (wmax.0 / pmax.0 - 1.0).abs() < 0.10,
        "{} vs {}",
        wmax.0,
        pmax.0
    );
}

/// With sharp interfaces (`[grid] interfaces = "sharp"`): the same scene,
/// each corner crossing the sphere's exact surface.
fn sharp(text: &str, opts: &Options) -> (eikon_grid::Medium, LightVolume, Summary) {
    let (scene, m) = medium(text);
    let regions = eikon_grid::Regions::new(&scene);
    let (v, s) = simulate_light_in(&scene.lights[0], &m, Some(&regions), opts, &|_, _| {}).unwrap();
    (m, v, s)
}

#[test]
fn with_sharp_interfaces_the_caustic_carries_the_power_ray_optics_gives() {
    const TOL: f64 = 0.03;
    let exact = exact_sphere::transmitted_power_in_shadow(&exact_sphere::fig7(), true, 1000);
    for res in [64, 128] {
        let (m, v, s) = sharp(&fig7(res), &Options::default());
        let p = shadow_power(&m, &v);
        println!(
            "{res}^3, sharp: {p:.4} W in the shadow ({:+.2}% against exact ray optics {exact:.4} W); torn {:.2e} of the entered power ({} pieces), reflected {:.4} W",
            100.0 * (p / exact - 1.0),
            s.torn_power[0] / s.entered[0],
            s.torn,
            s.reflected_power[0]
        );
        assert_eq!(s.caustic, 0);
        assert!(
            s.culled_power[0] < 1e-4 * s.entered[0],
            "culled {:?}",
            s.culled_power
        );
        assert!(s.energy_imbalance() < 1e-9, "{}", s.energy_imbalance());
        assert!(
            (p / exact - 1.0).abs() < TOL,
            "{res}^3: {p} W, exact {exact} W"
        );
    }
}

#[test]
fn with_sharp_interfaces_a_glass_ball_reads_what_the_photons_read() {
    let text = r#"
[grid]
resolution = 48
min = [-1, -1, -1]
max = [1, 1, 1]
interfaces = "sharp"

[[object]]
shape = { type = "sphere", center = [0.0, 0.35, 0.0], radius = 0.5 }
index = 1.5

[[light]]
type = "directional"
direction = [0.0, -1.0, 0.0]
power = [1, 1, 1]
"#;
    let (scene, m) = medium(text);
    let regions = eikon_grid::Regions::new(&scene);
    let light = &scene.lights[0];
    let opts = Options::default();
    let (wf, ws) = simulate_light_in(light, &m, Some(&regions), &opts, &|_, _| {}).unwrap();
    let count = 1_500_000;
    let (pa, psa) = simulate_photons_in(light, &m, Some(&regions), count, 1, &opts).unwrap();
    let (pb, _) = simulate_photons_in(light, &m, Some(&regions), count, 2, &opts).unwrap();
    let mut rel = Vec::new();
    let [nx, ny, nz] = m.geometry.dims;
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                let w = wf.fluence[[i, j, k, 0]];
                let p = 0.5 * (pa.fluence[[i, j, k, 0]] + pb.fluence[[i, j, k, 0]]);
                if p > 0.01 {
                    rel.push(((w / p - 1.0) as f64).abs());
                }
            }
        }
    }
    rel.sort_by(f64::total_cmp);
    let q = |f: f64| rel[((rel.len() - 1) as f64 * f) as usize];
    let (med, p95) = (q(0.5), q(0.95));
    println!(
        "sharp ball vs {} photons: {} cells, median |w / p - 1| {med:.4}, 95th percentile {p95:.4}; reflected wavefront {:.5} W, photons {:.5} W; torn {:.2e} of the entered power",
        2 * count,
        rel.len(),
        ws.reflected_power[0],
        psa.reflected_power[0],
        ws.torn_power[0] / ws.entered[0]
    );
    assert!(med < 0.02, "median {med}");
    assert!(p95 < 0.10, "95th percentile {p95}");
    // Both trace the reflected light (the default): the photons branch at
    // every crossing and leave none untraced; the wavefront leaves only
    // reflections below `REFLECT_MIN` of what their patch was emitted with.
    let (r, rp) = (ws.reflected_power[0], psa.reflected_power[0]);
    assert!(ws.reflections > 0 && psa.reflections > 0);
    assert_eq!(rp, 0.0, "photons left {rp} W of reflection untraced");
    assert!(
        r <= eikon_wavefront::propagate::REFLECT_MIN * ws.entered[0],
        "untraced reflection {r} W of {} W entered",
        ws.entered[0]
    );
}

#[test]
fn skipping_the_surface_tests_far_from_surfaces_changes_nothing() {
    // `Regions::clear_of` only saves work: the same volumes, bit for bit.
    let (scene, m) = medium(&fig7(48).replace("[grid]", "[grid]\ninterfaces = \"sharp\""));
    let light = &scene.lights[0];
    let opts = Options::default();
    let run = |regions: &eikon_grid::Regions| {
        let t = std::time::Instant::now();
        let (v, s) = simulate_light_in(light, &m, Some(regions), &opts, &|_, _| {}).unwrap();
        (v, s, t.elapsed().as_secs_f64())
    };
    let (a, sa, ta) = run(&eikon_grid::Regions::new(&scene));
    let (b, sb, tb) = run(&eikon_grid::Regions::new(&scene).clear_of(&m));
    println!(
        "sharp Fig. 7 at 48^3: {ta:.2} s testing every surface, {tb:.2} s skipping clear blocks"
    );
    assert_eq!(sa, sb);
    assert!(a.fluence == b.fluence && a.flux == b.flux);
}
