//! A light simulation with sharp interfaces on a medium of the surfaces
//! alone (`Medium::build_surfaces_within`, what `eikon simulate` builds for
//! the CPU): its rays and patches read each region's index and extinction
//! from the scene, so without the voxel index, gradient and extinction it
//! must give the very volumes and account the full medium gives. What
//! reads those voxels refuses it.

use eikon_grid::{Medium, Regions, Scene};
use eikon_wavefront::photons::simulate_photons_in;
use eikon_wavefront::{simulate_light_in, DepositRule, Error, LightVolume, Options, Summary};

/// A glass sphere and an absorbing slab around a point light, a clear
/// prism and a directional light: emission inside an absorbing region
/// (what the light loses within its start sphere), crossings, Fresnel
/// reflections traced on, absorption, and dispersion's three wavefronts.
const SCENE: &str = "[grid]\nresolution = 28\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
    dispersion = true\n\
    [ambient]\nindex = 1.0\n\
    [[object]]\nname = \"glass\"\n\
    shape = { type = \"sphere\", center = [0.2, 0.1, 0.0], radius = 0.45 }\n\
    index = [1.49, 1.5, 1.52]\nextinction = [0.3, 0.2, 0.1]\npriority = 2\n\
    [[object]]\nname = \"smoke\"\n\
    shape = { type = \"box\", center = [-0.5, -0.55, 0.0], size = [0.8, 0.7, 1.8] }\n\
    index = 1.2\nextinction = [2.0, 1.5, 1.0]\npriority = 1\n\
    [[light]]\ntype = \"point\"\nposition = [-0.5, -0.55, 0.05]\npower = [1, 1, 1]\n\
    [[light]]\ntype = \"directional\"\ndirection = [0.3, -1.0, 0.2]\npower = [1, 1, 1]\n";

fn scene() -> Scene {
    Scene::parse(SCENE, "surfaces test").unwrap()
}

fn run(scene: &Scene, m: &Medium, light: usize) -> (LightVolume, Summary) {
    let regions = Regions::new(scene).clear_of(m);
    simulate_light_in(
        &scene.lights[light],
        m,
        Some(&regions),
        &Options::default(),
        &|_, _| {},
    )
    .unwrap()
}

#[test]
fn the_surfaces_alone_give_the_full_mediums_volumes() {
    let scene = scene();
    let full = Medium::build(&scene).unwrap();
    let lean = Medium::build_surfaces_within(&scene, u128::MAX, &|_, _, _| {}).unwrap();
    assert!(full.has_voxel_fields() && !lean.has_voxel_fields());
    assert!(!lean.has_render_properties());
    // The regions skip crossing tests by the boundary indicator: the same.
    assert_eq!(full.boundary, lean.boundary);
    // Both media bound the index alike (the step limit and the
    // fixed-point scale derive from it): every region has cells of its
    // own here, so the raw and the smoothed index share their range.
    assert_eq!(full.index_range(), lean.index_range());
    assert_eq!(full.index_range(), (1.0, 1.52));
    for light in 0..scene.lights.len() {
        let (a, sa) = run(&scene, &full, light);
        let (b, sb) = run(&scene, &lean, light);
        assert_eq!(a.fluence, b.fluence, "light {light}: fluence");
        assert_eq!(a.flux, b.flux, "light {light}: flux");
        assert_eq!(
            format!("{sa:?}"),
            format!("{sb:?}"),
            "light {light}: the account"
        );
        // Something happened: light crossed, was absorbed and reflected.
        assert!(sa.absorbed_power[0] > 0.01 * sa.entered[0], "{sa:?}");
        assert!(sa.reflections > 0, "{sa:?}");
    }
}

#[test]
fn what_reads_the_voxels_refuses_the_surfaces_alone() {
    let scene = scene();
    let lean = Medium::build_surfaces_within(&scene, u128::MAX, &|_, _, _| {}).unwrap();
    let regions = Regions::new(&scene).clear_of(&lean);
    let light = &scene.lights[1];
    let refused =
        |r: Result<(LightVolume, Summary), Error>| matches!(r, Err(Error::NeedsVoxelFields(_)));
    let opts = Options::default();
    assert!(refused(simulate_light_in(
        light,
        &lean,
        None,
        &opts,
        &|_, _| {}
    )));
    let paper = Options {
        deposit: DepositRule::Paper,
        ..Options::default()
    };
    assert!(refused(simulate_light_in(
        light,
        &lean,
        Some(&regions),
        &paper,
        &|_, _| {}
    )));
    assert!(refused(simulate_photons_in(
        light,
        &lean,
        Some(&regions),
        1000,
        1,
        &opts
    )));
}

#[test]
fn the_surfaces_alone_are_refused_where_their_build_does_not_fit() {
    let scene = scene();
    let est = Medium::memory_estimate(&scene);
    assert!(est.surfaces < est.light && est.surfaces_peak < est.peak);
    let e = Medium::build_surfaces_within(&scene, est.surfaces_peak - 1, &|_, _, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("grid.resolution") && e.contains("lower the resolution"),
        "{e}"
    );
    assert!(Medium::build_surfaces_within(&scene, est.surfaces_peak, &|_, _, _| {}).is_ok());
}
