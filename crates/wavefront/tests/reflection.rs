//! The Fresnel-reflected light of the light simulation with sharp
//! interfaces (`propagate::reflection`): traced on as patches of its own,
//! checked against Fresnel's law at a plane surface and against an
//! independent photon tracer (`eikon_testkit::photon_ref`, which shares no
//! code with the simulation) on a glass sphere.

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
