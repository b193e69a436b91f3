//! The Fresnel-reflected light of the light simulation with sharp
//! interfaces (`propagate::reflection`): traced on as patches of its own,
//! checked against Fresnel's law at a plane surface, against an
//! independent photon tracer (`eikon_testkit::photon_ref`, which shares no
//! code with the simulation) on a glass sphere, and against the ray optics
//! of a sphere's reflected light, computed here ray by ray.

use eikon_grid::Regions;
use eikon_testkit::photon_ref::{self, Grid, Light, Sphere};
use eikon_testkit::scenes::medium;
use eikon_wavefront::photons::simulate_photons_in;
use eikon_wavefront::{simulate_light_in, LightVolume, Options, Summary};
use glam::DVec3;

#[path = "support/fresnel_slab.rs"]
mod fresnel_slab;
use fresnel_slab::Slab;

fn sharp(text: &str, reflections: bool) -> (LightVolume, Summary) {
    let (scene, m) = medium(text);
    let regions = Regions::new(&scene).clear_of(&m);
    let opts = Options {
        reflections,
        ..Options::default()
    };
    simulate_light_in(&scene.lights[0], &m, Some(&regions), &opts, &|_, _| {}).unwrap()
}

/// Mean of `f` over the cells `(i, j, k)` of an `n`^3 grid that `keep`
/// selects, and how many.
fn mean(
    n: usize,
    keep: impl Fn(usize, usize, usize) -> bool,
    f: impl Fn([usize; 3]) -> f64,
) -> (f64, usize) {
    let (mut sum, mut count) = (0.0, 0);
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                if keep(i, j, k) {
                    sum += f([i, j, k]);
                    count += 1;
                }
            }
        }
    }
    (sum / count as f64, count)
}

/// A plane wave meets a glass half-space (n = 1.5) at normal incidence:
/// `R = ((n - 1) / (n + 1))^2 = 0.04` of it is reflected. In front of the
/// surface the incident and the reflected waves overlap: fluence
/// `(1 + R) E`, net flux `(1 - R) E` along the incident direction. In the
/// glass: fluence and net flux `(1 - R) E`. Dropping the reflection (`reflections
/// = false`, `--no-reflections`) reads `E` in front.
#[test]
fn a_plane_wave_on_glass_is_reflected_by_fresnel() {
    let text = "[grid]\nresolution = 32\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
        [ambient]\nindex = 1.0\n\
        [[object]]\nname = \"glass\"\n\
        shape = { type = \"box\", center = [0.0, -1.6, 0.0], size = [4.0, 2.8, 4.0] }\n\
        index = 1.5\nextinction = [0, 0, 0]\n\
        [[light]]\ntype = \"directional\"\ndirection = [0, -1, 0]\npower = [1, 1, 1]\n";
    let r = 0.04;
    let n = 32;
    // Cells well in front (y > 0.1) and well inside (y < -0.5), away from
    // the grid's sides.
    let side = |i: usize, k: usize| (3..n - 3).contains(&i) && (3..n - 3).contains(&k);
    let front = |i, j, k| side(i, k) && j >= 18 && j < n - 2;
    let glass = |i, j, k| side(i, k) && (2..7).contains(&j);
    for (reflections, want_front, want_flux) in [(true, 1.0 + r, 1.0 - r), (false, 1.0, 1.0)] {
        let (v, s) = sharp(text, reflections);
        let fluence = |ix: [usize; 3]| f64::from(v.fluence[[ix[0], ix[1], ix[2], 0]]);
        let flux = |ix: [usize; 3]| f64::from(v.flux[0][[ix[0], ix[1], ix[2], 1]]);
        let (e_front, cells) = mean(n, front, fluence);
        let (f_front, _) = mean(n, front, flux);
        let (e_glass, _) = mean(n, glass, fluence);
        let (f_glass, _) = mean(n, glass, flux);
        println!(
            "reflections {reflections}: front fluence {e_front:.5} net flux {f_front:.5} \
             ({cells} cells), glass fluence {e_glass:.5} net flux {f_glass:.5}; \
             {} reflected patches, reflected (untraced) {:.5} W, energy imbalance {:.1e}",
            s.reflections,
            s.reflected_power[0],
            s.energy_imbalance()
        );
        assert!(
            (e_front - want_front).abs() < 2e-3,
            "front fluence {e_front}, want {want_front}"
        );
        assert!(
            (f_front + want_flux).abs() < 2e-3,
            "front net flux {f_front}"
        );
        assert!(
            (e_glass - (1.0 - r)).abs() < 2e-3,
            "glass fluence {e_glass}"
        );
        assert!(
            (f_glass + (1.0 - r)).abs() < 2e-3,
            "glass net flux {f_glass}"
        );
        assert!(s.energy_imbalance() < 1e-9, "{s:?}");
        if reflections {
            assert!(s.reflections > 0);
            // What reached the surface at normal incidence is all traced.
            assert!(s.reflected_power[0] < 1e-3 * s.entered[0], "{s:?}");
        } else {
            assert_eq!(s.reflections, 0);
        }
    }
}

/// A glass sphere (n = 1.5, weakly absorbing) under a tilted plane wave,
/// against the independent photon tracer with every reflection traced:
/// the mean fluence inside the sphere and in the shell of air around it
/// agree within the tracer's noise and the deposit's. With the reflected
/// light dropped, the inside reads several percent low (the light that
/// reflects back inside at the exit would have crossed it again), which
/// this test tells apart.
#[test]
fn a_glass_sphere_agrees_with_independent_photons() {
    let n = 48;
    let text = format!(
        "[grid]\nresolution = {n}\nmin = [-1.0, -1.0, -1.0]\nmax = [1.0, 1.0, 1.0]\n\
         [ambient]\nindex = 1.0\n\
         [[object]]\nname = \"glass sphere\"\n\
         shape = {{ type = \"sphere\", center = [0.0, 0.15, 0.0], radius = 0.45 }}\n\
         index = 1.5\nextinction = [0.05, 0.03, 0.03]\npriority = 1\n\
         [[light]]\ntype = \"directional\"\ndirection = [0.2, -1.0, 0.1]\npower = [1.0, 1.0, 1.0]\n"
    );
    let sphere = Sphere {
        centre: DVec3::new(0.0, 0.15, 0.0),
        radius: 0.45,
        index: 1.5,
        extinction: [0.05, 0.03, 0.03],
    };
    let grid = Grid {
        min: DVec3::splat(-1.0),
        max: DVec3::splat(1.0),
        dims: [n; 3],
    };
    let reference = photon_ref::simulate(
        &photon_ref::Scene {
            grid,
            sphere: Some(sphere),
            light: Light::Directional {
                direction: DVec3::new(0.2, -1.0, 0.1),
                irradiance: [1.0; 3],
            },
            reflections: true,
        },
        1 << 22,
        7,
    );
    let h = 2.0 / n as f64;
    let at = |i: usize, j: usize, k: usize| grid.centre(i, j, k) - sphere.centre;
    let inside = |i, j, k| at(i, j, k).length() < sphere.radius - 1.5 * h;
    let shell = |i, j, k| {
        let r = at(i, j, k).length();
        r > sphere.radius + 1.5 * h && r < sphere.radius + 6.0 * h
    };
    let truth = |ix: [usize; 3]| reference.fluence[[ix[0], ix[1], ix[2], 0]];
    let (ref_in, cells_in) = mean(n, inside, truth);
    let (ref_shell, cells_shell) = mean(n, shell, truth);
    println!("photons: inside {ref_in:.5} ({cells_in} cells), shell {ref_shell:.5} ({cells_shell} cells)");
    for (reflections, close) in [(true, true), (false, false)] {
        let (v, s) = sharp(&text, reflections);
        let est = |ix: [usize; 3]| f64::from(v.fluence[[ix[0], ix[1], ix[2], 0]]);
        let (w_in, _) = mean(n, inside, est);
        let (w_shell, _) = mean(n, shell, est);
        let (d_in, d_shell) = (w_in / ref_in - 1.0, w_shell / ref_shell - 1.0);
        println!(
            "reflections {reflections}: inside {w_in:.5} ({d_in:+.4}), shell {w_shell:.5} ({d_shell:+.4}); \
             {} reflected patches, untraced reflected {:.5} of {:.5} W entered",
            s.reflections, s.reflected_power[0], s.entered[0]
        );
        assert!(s.energy_imbalance() < 1e-9, "{s:?}");
        if close {
            assert!(d_in.abs() < 0.01, "inside: {d_in:+.4}");
            assert!(d_shell.abs() < 0.005, "shell: {d_shell:+.4}");
            // Only what reflects off torn pieces' silhouettes, or farther
            // back than the reach, goes untraced.
            assert!(s.reflected_power[0] < 1e-3 * s.entered[0], "{s:?}");
        } else {
            assert!(
                d_in < -0.05,
                "without reflections the inside should read low: {d_in:+.4}"
            );
        }
    }
}

/// Oblique incidence, from air into glass and from glass into air (up to
/// near the critical angle, 41.8 degrees): the reflected wave is the
/// mirror image of the incident one with `R` of its irradiance (Fresnel,
/// written out in `support/fresnel_slab.rs`), the transmitted one `1 - R`
/// of it narrowed or widened by `cos_i / cos_t`.
#[test]
fn oblique_waves_reflect_and_refract_by_fresnel() {
    for (deg, from_air) in [
        (30.0, true),
        (60.0, true),
        (20.0, false),
        (35.0, false),
        (40.0, false),
    ] {
        for reflections in [true, false] {
            let slab = Slab { deg, from_air };
            let (v, s) = sharp(&slab.scene(), reflections);
            let ([wn, en], [wf, ef]) = slab.measure(&v, reflections);
            println!(
                "{deg} degrees from {}, reflections {reflections}: near {en:.5} (want {wn:.5}), \
                 far {ef:.5} (want {wf:.5}); untraced reflected {:.4} of {:.4} W",
                if from_air { "air" } else { "glass" },
                s.reflected_power[0],
                s.entered[0]
            );
            assert!(
                (en / wn - 1.0).abs() < 5e-4,
                "{deg} {from_air} {reflections}: near {en} want {wn}"
            );
            assert!(
                (ef / wf - 1.0).abs() < 5e-4,
                "{deg} {from_air} {reflections}: far {ef} want {wf}"
            );
            assert!(s.energy_imbalance() < 1e-9, "{s:?}");
        }
    }
}

/// The layer of cells a glass surface cuts, and the next layer on the
/// incident side, at normal incidence from either side and at 40 degrees
/// from the air: each cell reads the exact average of the two sides'
/// waves (`Slab::cut_layers`). A patch carries all its light on until its
/// corners have all crossed, so the light it puts beyond the surface is
/// weighted by what the surface let through
/// (`propagate::straddle_weights`); unweighted, the cut cells read 0.8%
/// high at normal incidence. In the step that bends a patch's corners the
/// two pieces of its tube are cut into the same sub-patches
/// (`propagate::bent_tube`); cut apart, at 40 degrees the layer above the
/// cut one read 2% high and the cut one 2.7% low. The cut layer reads
/// within 5e-4 at normal incidence and within 5e-3 at 40 degrees, where
/// each sub-patch's path through the bend is the straight interpolation of
/// its corners', which cuts the corner of the bent rays; every other layer
/// within 5e-4.
#[test]
fn the_cells_a_surface_cuts_read_what_it_lets_through() {
    for (deg, from_air, cut_tolerance) in
        [(0.0, true, 5e-4), (0.0, false, 5e-4), (40.0, true, 5e-3)]
    {
        for reflections in [true, false] {
            let slab = Slab { deg, from_air };
            let (v, s) = sharp(&slab.scene(), reflections);
            let [[want, read], [want_next, read_next]] = slab.cut_layers(&v, reflections);
            println!(
                "{deg} degrees, from the air {from_air}, reflections {reflections}: cut layer \
                 {read:.5} (want {want:.5}), next {read_next:.5} (want {want_next:.5})"
            );
            assert!(
                (read / want - 1.0).abs() < cut_tolerance,
                "{deg} {from_air} {reflections}: {read}, want {want}"
            );
            assert!(
                (read_next / want_next - 1.0).abs() < 5e-4,
                "{deg} {from_air} {reflections}: next {read_next}, want {want_next}"
            );
            assert!(s.energy_imbalance() < 1e-9, "{s:?}");
        }
    }
}

/// eikon's own photons (`--method photons`) branch at a sharp crossing:
/// the reflected part goes on as a photon of its own. On the slab of
/// `a_plane_wave_on_glass_is_reflected_by_fresnel` (60 degrees from the
/// air) they read `1 + R` on the incident side and `(1 - R) cos_i / cos_t`
/// beyond, within 0.5% (the mean of thousands of cells; the photons'
/// noise is far below that), and 1 on the incident side without.
#[test]
fn photons_branch_where_light_reflects() {
    let slab = Slab {
        deg: 60.0,
        from_air: true,
    };
    let (scene, m) = medium(&slab.scene());
    let regions = Regions::new(&scene).clear_of(&m);
    for reflections in [true, false] {
        let opts = Options {
            reflections,
            ..Options::default()
        };
        let (v, s) =
            simulate_photons_in(&scene.lights[0], &m, Some(&regions), 200_000, 1, &opts).unwrap();
        let ([wn, en], [wf, ef]) = slab.measure(&v, reflections);
        println!(
            "photons, reflections {reflections}: near {en:.5} (want {wn:.5}), far {ef:.5} \
             (want {wf:.5}); {} branches, untraced reflected {:.4} W",
            s.reflections, s.reflected_power[0]
        );
        assert!((en / wn - 1.0).abs() < 5e-3, "near {en}, want {wn}");
        assert!((ef / wf - 1.0).abs() < 5e-3, "far {ef}, want {wf}");
        assert!(s.energy_imbalance() < 1e-9, "{s:?}");
        assert_eq!(s.reflections > 0, reflections);
    }
}

/// Unpolarized Fresnel reflectance from index `n1` into `n2` at incidence
/// cosine `cos_i`, written out here (not the engine's `fresnel`).
fn fresnel_r(cos_i: f64, n1: f64, n2: f64) -> f64 {
    let sin_t = n1 / n2 * (1.0 - cos_i * cos_i).max(0.0).sqrt();
    if sin_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin_t * sin_t).sqrt();
    let rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t);
    let rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// A 2D ray of the sphere's plane of incidence: position and unit
/// direction, `(u, v)` with `v` pointing back towards the light.
type Ray2 = ([f64; 2], [f64; 2]);

/// The rays a sphere of radius `a`, index `n` and extinction `sigma` (in
/// air, centred at the origin) sends out of a ray of impact parameter `b`
/// arriving along `-v`, other than the one it transmits straight through:
/// the outer reflection, and the rays that leave after `p = 1..=max_p`
/// reflections inside. Each with its share of the ray's flux.
fn sphere_rays_sent_out(a: f64, n: f64, sigma: f64, b: f64, max_p: usize) -> Vec<(Ray2, f64)> {
    let dot = |x: [f64; 2], y: [f64; 2]| x[0] * y[0] + x[1] * y[1];
    let (d, p) = ([0.0, -1.0], [b, (a * a - b * b).max(0.0).sqrt()]);
    let nrm = [p[0] / a, p[1] / a];
    let cos_i = -dot(d, nrm);
    let r_out = fresnel_r(cos_i, 1.0, n);
    let mirror = |d: [f64; 2], m: [f64; 2]| {
        let k = 2.0 * dot(d, m);
        [d[0] - k * m[0], d[1] - k * m[1]]
    };
    let mut out = vec![((p, mirror(d, nrm)), r_out)];
    // Refracted in: the tangential part scaled by 1/n.
    let eta = 1.0 / n;
    let cos_t = (1.0 - eta * eta * (1.0 - cos_i * cos_i)).sqrt();
    let mut dir = [
        eta * d[0] + (eta * cos_i - cos_t) * nrm[0],
        eta * d[1] + (eta * cos_i - cos_t) * nrm[1],
    ];
    let mut at = p;
    let mut carried = 1.0 - r_out;
    for hit in 0..=max_p {
        // The chord to the sphere's far side (|at| = a), absorbing.
        let t = -2.0 * dot(at, dir);
        at = [at[0] + t * dir[0], at[1] + t * dir[1]];
        carried *= (-sigma * t).exp();
        let m = [at[0] / a, at[1] / a];
        let c = dot(dir, m);
        let r = fresnel_r(c, n, 1.0);
        if hit > 0 {
            // Out into the air: the tangential part scaled by n.
            let sin2 = n * n * (1.0 - c * c);
            let cos_o = (1.0 - sin2).max(0.0).sqrt();
            let o = [
                n * dir[0] + (cos_o - n * c) * m[0],
                n * dir[1] + (cos_o - n * c) * m[1],
            ];
            out.push(((at, o), carried * (1.0 - r)));
        }
        carried *= r;
        dir = mirror(dir, m);
    }
    out
}

/// The light a glass sphere sends out besides what it transmits
/// straight through (its outer reflection, and the light that leaves after
/// one or more reflections inside: the rainbow's family and beyond), against
/// ray optics computed here from Snell's and Fresnel's laws alone. The
/// wavefront with reflections traced, less the wavefront without, is that
/// light: both transmit the same `1 - R` at each crossing. Its fluence is
/// weighed over a shell of air around the sphere with smooth weights in
/// distance and in the angle from the light's direction (bins that add up to
/// one); the reference integrates the same weights along each ray out of the
/// sphere (impact parameter by impact parameter, every family up to eight
/// reflections inside), ray by ray the exact track-length measure of what
/// the volume's cells hold. The outer reflection diverges: its patches are
/// dim and grow over a voxel wide unsplit, the patches
/// `deposit::SUBPATCHES_PER_SIDE` is about.
///
/// Allowed besides 2% of each bin: what the wavefront reports it did not
/// follow. Its reflections below `REFLECT_MIN` (their power times the
/// longest weighted path; they are reflections inside, so no more than
/// the light that survives a chord), and the thin tubes (pieces of patches
/// torn at the silhouette, at the smallest split) still torn there, which
/// end with their power counted as torn: taken as the outermost ring of
/// impact parameters carrying that power, where ray optics sends its light at grazing
/// incidence (mostly forward, where `R` nears one).
fn the_light_a_sphere_sends_out_matches_ray_optics(sigma: f64) {
    let (res, a, n_glass) = (128, 0.3, 1.5);
    let text = sphere_under_light(res, 0.0, a, n_glass, sigma);
    let light = DVec3::new(0.2, -1.0, 0.1).normalize();
    // Weights: a radial window over [0.42, 0.85] with sin^2 tapers 0.1
    // wide (inside the grid, clear of the sphere), times cos^2 hats in mu =
    // cos(angle from the light's direction), 0.4 apart.
    let (r0, r1, taper) = (0.42, 0.85, 0.1);
    let quarter = 0.5 * std::f64::consts::PI;
    let radial = |r: f64| {
        let s = |x: f64| (quarter * x.clamp(0.0, 1.0)).sin().powi(2);
        s((r - r0) / taper) * s((r1 - r) / taper)
    };
    let centres = [-1.0, -0.6, -0.2, 0.2, 0.6, 1.0];
    let width = 0.4;
    let weights = |r: f64, mu: f64| {
        let w = radial(r);
        centres.map(|c| {
            let u = (mu - c) / width;
            if u.abs() < 1.0 {
                w * (quarter * u).cos().powi(2)
            } else {
                0.0
            }
        })
    };
    // Ray optics: irradiance 1 over rings of impact parameter b = a sin
    // theta (area 2 pi b db), each ray out of the sphere weighed along its
    // straight path; kept ring by ring for the allowance.
    let (rings, ds) = (3000, 2.5e-3);
    let dtheta = quarter / rings as f64;
    let by_ring: Vec<(f64, [f64; 6])> = (0..rings)
        .map(|i| {
            let theta = (i as f64 + 0.5) * dtheta;
            let b = a * theta.sin();
            let area = 2.0 * std::f64::consts::PI * a * a * theta.sin() * theta.cos() * dtheta;
            let mut bins = [0.0; 6];
            for ((p, d), share) in sphere_rays_sent_out(a, n_glass, sigma, b, 8) {
                let mut s = 0.5 * ds;
                loop {
                    let x = [p[0] + s * d[0], p[1] + s * d[1]];
                    let r = (x[0] * x[0] + x[1] * x[1]).sqrt();
                    if r > r1 && x[0] * d[0] + x[1] * d[1] > 0.0 {
                        break;
                    }
                    // v points back towards the light: mu = -v / r.
                    for (acc, w) in bins.iter_mut().zip(weights(r, -x[1] / r)) {
                        *acc += area * share * w * ds;
                    }
                    s += ds;
                }
            }
            (b, bins)
        })
        .collect();
    let reference: [f64; 6] =
        std::array::from_fn(|k| by_ring.iter().map(|(_, bins)| bins[k]).sum());
    let (with, s_with) = sharp(&text, true);
    let (without, s_without) = sharp(&text, false);
    assert!(s_with.energy_imbalance() < 1e-9, "{s_with:?}");
    let h = 2.0 / res as f64;
    let mut got = [0.0; 6];
    for i in 0..res {
        for j in 0..res {
            for k in 0..res {
                let x = DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * h - DVec3::ONE;
                let r = x.length();
                if r < r0 || r > r1 {
                    continue;
                }
                let d = f64::from(with.fluence[[i, j, k, 0]])
                    - f64::from(without.fluence[[i, j, k, 0]]);
                for (acc, w) in got.iter_mut().zip(weights(r, x.dot(light) / r)) {
                    *acc += d * w * h * h * h;
                }
            }
        }
    }
    let untraced = s_with.reflected_power[0];
    let torn = s_with.torn_power[0];
    // The outermost ring that carries the torn power (irradiance 1).
    let edge = a - torn / (2.0 * std::f64::consts::PI * a);
    let at_edge: [f64; 6] = std::array::from_fn(|k| {
        by_ring
            .iter()
            .filter(|(b, _)| *b > edge)
            .map(|(_, bins)| bins[k])
            .sum()
    });
    println!(
        "untraced reflected {untraced:.2e} W, torn {torn:.2e} W ({} pieces; {:.2e} W without \
         reflections), of {:.4} W entered; without reflections {:.4e} W reflected",
        s_with.torn, s_without.torn_power[0], s_with.entered[0], s_without.reflected_power[0]
    );
    // Only light reflected inside can go untraced: at most what enters
    // and survives the shortest chord (2 a cos of the critical angle).
    let chord = 2.0 * a * (1.0 - 1.0 / (n_glass * n_glass)).sqrt();
    let inside = std::f64::consts::PI * a * a * (-sigma * chord).exp();
    let untraced_bound = untraced.min(inside);
    for k in 0..6 {
        let (g, want) = (got[k], reference[k]);
        let allowance = 0.02 * want + at_edge[k] + 0.45 * untraced_bound;
        println!(
            "mu {:+.1}: wavefront {g:.5e}, ray optics {want:.5e} ({:+.4}); allowed {allowance:.2e} \
             ({:.2e} of it the torn ring's)",
            centres[k],
            g / want - 1.0,
            at_edge[k]
        );
        assert!(
            (g - want).abs() < allowance,
            "mu {:+.1}: {g:.5e} against {want:.5e} (allowed {allowance:.2e})",
            centres[k]
        );
    }
}

/// [`the_light_a_sphere_sends_out_matches_ray_optics`] for a clear sphere:
/// the outer reflection and every family of rays reflected inside.
#[test]
fn the_light_a_clear_sphere_sends_out_matches_ray_optics() {
    the_light_a_sphere_sends_out_matches_ray_optics(0.0);
}

/// [`the_light_a_sphere_sends_out_matches_ray_optics`] for a sphere that
/// absorbs what enters it (extinction 20: over its shortest chord inside
/// it keeps 1e-4), so that little but the outer reflection leaves it.
/// The steps that carry a patch across the surface charge it the glass's
/// absorption before the Fresnel split; the reflected part never entered,
/// and gets it back when traced (`propagate::crossing_done`): without
/// that the reflection read several percent low.
#[test]
fn the_light_an_absorbing_sphere_reflects_matches_ray_optics() {
    the_light_a_sphere_sends_out_matches_ray_optics(20.0);
}

/// A clear glass torus (n = 1.6) under an oblique directional light, at
/// 32^3: light is torn at its silhouettes and held by total internal
/// reflection in its tube for thousands of steps, and its pieces finish
/// crossing a surface at corners of their own. A traced reflection must
/// carry what the surface took from its patch, no more: the untraced
/// reflected light left in the tally is never negative, and nothing
/// leaves the grid that did not enter it. (A reflection made of the
/// Fresnel factors of a piece's own corners, when its flux had taken its
/// parent's, sent out 1.93 W of the 1.53 W that entered, and the tally of
/// untraced reflected light read -0.50 W.)
#[test]
fn a_clear_torus_sends_out_no_more_light_than_entered() {
    let text = r#"
[grid]
resolution = 32
min = [-0.5, -0.5, -0.5]
max = [0.5, 0.5, 0.5]

[[object]]
shape = { type = "torus", center = [0.0, 0.0, 0.0], major_radius = 0.28, minor_radius = 0.1 }
index = 1.6

[[light]]
type = "directional"
direction = [0.4, -1.0, 0.3]
power = [1.0, 1.0, 1.0]
"#;
    let (_, s) = sharp(text, true);
    println!("{s:?}");
    assert!(
        s.reflections > 1000 && s.torn > 1000,
        "the torus reflects and tears: {s:?}"
    );
    for c in 0..3 {
        let e = s.entered[c];
        assert!(
            s.absorbed_power[c].abs() < 1e-12 * e,
            "clear glass absorbs nothing"
        );
        for (what, p) in [
            ("exited", s.exited_power[c]),
            ("reflected", s.reflected_power[c]),
            ("torn", s.torn_power[c]),
            ("trapped", s.trapped_power[c]),
        ] {
            assert!(p >= -1e-9 * e && p <= e, "{what} {p} of {e} entered");
        }
        // What is not traced on (dropped at a silhouette, untraced
        // reflections, still travelling) is a small part of it.
        let left = s.reflected_power[c] + s.torn_power[c] + s.trapped_power[c];
        assert!(left < 0.05 * e, "{left} of {e} not traced to the end");
    }
    assert!(s.energy_imbalance() < 1e-9, "{}", s.energy_imbalance());
}

/// A sphere of radius `a` at `(0, y, 0)` in `[-1, 1]^3` at `res`^3, index
/// `n_glass` and extinction `sigma`, in vacuum under a directional light of
/// irradiance 1 along `(0.2, -1, 0.1)`.
fn sphere_under_light(res: usize, y: f64, a: f64, n_glass: f64, sigma: f64) -> String {
    format!(
        "[grid]\nresolution = {res}\nmin = [-1.0, -1.0, -1.0]\nmax = [1.0, 1.0, 1.0]\n\
         [ambient]\nindex = 1.0\n\
         [[object]]\nname = \"sphere\"\n\
         shape = {{ type = \"sphere\", center = [0.0, {y:?}, 0.0], radius = {a} }}\n\
         index = {n_glass}\nextinction = [{sigma}, {sigma}, {sigma}]\npriority = 1\n\
         [[light]]\ntype = \"directional\"\ndirection = [0.2, -1.0, 0.1]\npower = [1.0, 1.0, 1.0]\n"
    )
}

/// Unpolarized Fresnel reflectance from index 1 into `n` at incidence
/// `cos_i` (written out here, not the engine's).
fn reflectance_into(n: f64, cos_i: f64) -> f64 {
    let sin_t = (1.0 - cos_i * cos_i).max(0.0).sqrt() / n;
    let cos_t = (1.0 - sin_t * sin_t).sqrt();
    let rs = (cos_i - n * cos_t) / (cos_i + n * cos_t);
    let rp = (n * cos_i - cos_t) / (n * cos_i + cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// Light that grazes a sphere's silhouette carries on. An absorbing glass
/// sphere under a directional light of irradiance 1, its reflected light
/// not traced, absorbs what ray optics gives: at impact parameter `b` a
/// ray enters with `T = 1 - R(theta_i)` and loses `1 - exp(-sigma L)` on
/// its chord `L = 2 a cos(theta_t)`; what reflects at the back leaves the
/// beam. So the absorbed power is `int_0^a T (1 - exp(-sigma L)) 2 pi b db`
/// (midpoint rule here). Patches straddling the rim are split down to the
/// smallest split, and a piece still torn there goes on as a thin tube
/// about its centre ray. When those pieces were dropped instead (5.4e-3 W
/// of them, counted as torn), the sphere absorbed 0.136% too little at
/// 64^3; with thin tubes 0.022%.
///
/// The reflected light (tallied, not traced) must be ray optics' too:
/// `int_0^a (R + T exp(-sigma L) R) 2 pi b db`. When each corner took its
/// Fresnel factor from the patch as it crossed, two errors nearly
/// cancelled in the absorbed power (-0.022%): the reflected share was
/// charged the glass's absorption while the patch straddled the surface,
/// and the factors' geometric mean reflected too much near the rim. With
/// that absorption given back, the sphere absorbed 0.29% less than ray
/// optics and reflected 1.5% more (26% more at extinction 200). A patch is
/// now split by Fresnel once all its corners have crossed
/// (`propagate::crossing_done`).
#[test]
fn an_absorbing_sphere_absorbs_what_ray_optics_gives_up_to_its_rim() {
    let (res, a, n_glass, sigma) = (64, 0.45, 1.5, 2.0);
    let text = sphere_under_light(res, 0.1, a, n_glass, sigma);
    let samples = 200_000;
    let db = a / samples as f64;
    // Absorbed, and reflected (at the entry, and at the back what
    // survives the chord), over rings of impact parameter.
    let (exact, exact_reflected) = (0..samples)
        .map(|k| {
            let b = (k as f64 + 0.5) * db;
            let cos_i = (1.0 - (b / a) * (b / a)).sqrt();
            let sin_t = (b / a) / n_glass;
            let chord = 2.0 * a * (1.0 - sin_t * sin_t).sqrt();
            let r = reflectance_into(n_glass, cos_i);
            let (t, left) = (1.0 - r, (-sigma * chord).exp());
            let ring = 2.0 * std::f64::consts::PI * b * db;
            // At the back the incidence is theta_t: R is the same.
            (t * (1.0 - left) * ring, (r + t * left * r) * ring)
        })
        .fold((0.0, 0.0), |(x, y), (p, q)| (x + p, y + q));
    let (_, s) = sharp(&text, false);
    let got = s.absorbed_power[0];
    let reflected = s.reflected_power[0];
    println!(
        "absorbed {got:.6} W, ray optics {exact:.6} W ({:+.3}%); reflected {reflected:.6} W, ray \
         optics {exact_reflected:.6} W ({:+.3}%); torn {:.2e} W in {} thin tubes; trapped {:.2e} W",
        100.0 * (got / exact - 1.0),
        100.0 * (reflected / exact_reflected - 1.0),
        s.torn_power[0],
        s.torn,
        s.trapped_power[0]
    );
    assert!(s.energy_imbalance() < 1e-9, "{}", s.energy_imbalance());
    assert!(
        (got / exact - 1.0).abs() < 1e-3,
        "absorbed {got} W, ray optics {exact} W"
    );
    assert!(
        (reflected / exact_reflected - 1.0).abs() < 5e-3,
        "reflected {reflected} W, ray optics {exact_reflected} W"
    );
}
