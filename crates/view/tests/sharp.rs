//! The renderer with sharp interfaces (`[grid] interfaces = "sharp"`)
//! against geometry and Fresnel computed here independently: the
//! silhouette of a glass sphere, and the reflection of a glass wall one
//! voxel thick.
//!
//! `cargo test --release -p eikon-view --test sharp -- --nocapture` prints
//! the measured figures beside those of the smoothed interfaces.

use eikon_grid::{Medium, Scene};
use eikon_optics::Image;
use eikon_testkit::scenes::camera;
use eikon_view::background::load_environment;
use eikon_view::{Options, Renderer, Surroundings};
use glam::DVec3;

fn render(scene: &Scene, sharp: bool) -> Image {
    let medium = Medium::build(scene).expect("test scene voxelizes");
    let env = load_environment(&scene.background).unwrap();
    let s = Surroundings::new(scene, env, &[], &medium.geometry);
    let cam = camera(scene);
    let mut r = Renderer::new(&medium, &[], &s, &cam, Options::default());
    if sharp {
        r = r.sharp(scene);
    }
    r.render(&|_, _| {}).0
}

/// Unpolarized Fresnel reflectance from the textbook amplitudes (Born &
/// Wolf), from the independent photon tracer rather than `eikon-optics`.
fn fresnel(cos_i: f64, n1: f64, n2: f64) -> f64 {
    eikon_testkit::photon_ref::fresnel(cos_i, n1, n2).0
}

/// An opaque glass sphere (n = 1.5, extinction so high that even a grazing
/// chord is black) in front of a white sky: a pixel centre that meets the
/// sphere shows only its Fresnel reflection R of the sky, one that misses
/// shows 1. The pixels darker than 0.75 (R < 0.75 up to about 88 degrees
/// of incidence) are counted in the render and, for the same camera rays,
/// with an exact ray-sphere test here; the silhouette radius `sqrt(count /
/// pi)` must agree to half a pixel at 128^3.
#[test]
fn the_silhouette_of_a_glass_sphere_is_exact() {
    const TOL_PX: f64 = 0.5;
    let c = DVec3::new(0.0, 0.0, 0.0);
    let r = 0.5;
    let text = |mode: &str| {
        format!(
            r#"
[grid]
resolution = 128
min = [-1, -1, -1]
max = [1, 1, 1]
interfaces = "{mode}"

[[object]]
name = "ball"
shape = {{ type = "sphere", center = [{}, {}, {}], radius = {r} }}
index = 1.5
extinction = [1e5, 1e5, 1e5]

[camera]
position = [0.0, 0.3, 3.0]
target = [0.0, 0.0, 0.0]
fov = 24
resolution = [200, 200]

[background]
type = "constant"
color = [1, 1, 1]
"#,
            c.x, c.y, c.z
        )
    };
    let sharp = Scene::parse(&text("sharp"), "silhouette").unwrap();
    let cam = camera(&sharp);
    let voxel = sharp.grid.geometry.voxel_size();
    // The exact count: pixel centres' rays (one sample, as rendered).
    let mut exact = 0usize;
    let (w, h) = (cam.width(), cam.height());
    for y in 0..h {
        for x in 0..w {
            let (o, d) = cam.ray(x, y, 0, Options::default().seed);
            let oc = o - c;
            let b = oc.dot(d);
            let disc = b * b - (oc.length_squared() - r * r);
            if disc > 0.0 {
                let t = -b - disc.sqrt();
                let normal = (o + d * t - c) / r;
                if fresnel(-d.dot(normal), 1.0, 1.5) < 0.75 {
                    exact += 1;
                }
            }
        }
    }
    let radius = |img: &Image| {
        let n = img.data.iter().filter(|p| p[1] < 0.75).count();
        (n as f64 / std::f64::consts::PI).sqrt()
    };
    let want = (exact as f64 / std::f64::consts::PI).sqrt();
    let got = radius(&render(&sharp, true));
    let smoothed = radius(&render(
        &Scene::parse(&text("smoothed"), "silhouette").unwrap(),
        false,
    ));
    // Pixels per voxel at the sphere's distance, to read the shifts in voxels.
    let focal = 0.5 * h as f64 / (0.5 * 24f64.to_radians()).tan();
    let px_per_voxel = focal * voxel / (cam.position() - c).length();
    println!(
        "silhouette radius: exact {want:.3} px, sharp {got:.3} px ({:+.3} px), smoothed {smoothed:.3} px ({:+.3} px = {:+.2} voxel)",
        got - want,
        smoothed - want,
        (smoothed - want) / px_per_voxel
    );
    assert!(
        (got - want).abs() <= TOL_PX,
        "sharp silhouette radius {got} px, exact {want} px"
    );
}

/// A glass wall one voxel thick (n = 1.5), seen at 30 degrees: each of its
/// two faces reflects the white plane behind the camera with Fresnel's R
/// (the same R at both, by reciprocity), and everything transmitted goes
/// into black. The eye sees `R + (1 - R) R`, which must hold to 1%.
#[test]
fn a_wall_one_voxel_thick_reflects_at_both_faces() {
    const TOL_REL: f64 = 0.01;
    let text = |mode: &str| {
        format!(
            r#"
[grid]
resolution = 128
min = [-1, -1, -1]
max = [1, 1, 1]
interfaces = "{mode}"

[[object]]
name = "wall"
shape = {{ type = "box", center = [0, 0, 0], size = [1.6, 1.6, 0.015625] }}
index = 1.5

[camera]
position = [0.0, 1.5, 2.598076211353316]
target = [0.0, 0.0, 0.0]
fov = 4
resolution = [9, 9]

[background]
type = "checker"
point = [0, 0, 6]
normal = [0, 0, -1]
square = 100
colors = [[1, 1, 1], [1, 1, 1]]
"#
        )
    };
    let r = fresnel(30f64.to_radians().cos(), 1.0, 1.5);
    let want = r + (1.0 - r) * r;
    let mean =
        |img: &Image| img.data.iter().map(|p| p[1] as f64).sum::<f64>() / img.data.len() as f64;
    let sharp = mean(&render(
        &Scene::parse(&text("sharp"), "wall").unwrap(),
        true,
    ));
    let smoothed = mean(&render(
        &Scene::parse(&text("smoothed"), "wall").unwrap(),
        false,
    ));
    println!(
        "one-voxel wall at 30 deg: R + (1 - R) R = {want:.5}; sharp {sharp:.5} ({:+.2}%), smoothed {smoothed:.5} ({:+.2}%)",
        100.0 * (sharp / want - 1.0),
        100.0 * (smoothed / want - 1.0)
    );
    assert!(
        (sharp / want - 1.0).abs() <= TOL_REL,
        "sharp wall reflects {sharp}, want {want}"
    );
}

/// [Ihrke07 fig 7]'s glass sphere over its plane, light and eye both with
/// sharp interfaces at 128^3: the plane's pixels darker than half the lit
/// plane, against the same count from exact ray optics computed here (the
/// plane's irradiance: the direct light where the line to the light misses
/// the sphere, plus the light it sends on, binned on the plane from a dense
/// grid of rays: reflected off it, and refracted in and out after any
/// number of inner reflections, with Fresnel and the glass's extinction).
/// The light simulation traces the reflected light by default, so the
/// reference does too.
/// Pixels that see the sphere itself are left out of both.
#[test]
fn the_shadow_under_the_glass_sphere_matches_exact_ray_optics() {
    const TOL: f64 = 0.03;
    let c = DVec3::new(0.0, 0.15, 0.0);
    let r = 0.45;
    let n = 1.5;
    let sigma = 0.03; // the green channel's extinction
    let plane_y = -0.9;
    let text = format!(
        r#"
[grid]
resolution = 128
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 1.0]
interfaces = "sharp"

[[object]]
shape = {{ type = "sphere", center = [{}, {}, {}], radius = {r} }}
index = {n}
extinction = [0.05, {sigma}, 0.03]

[[light]]
type = "directional"
direction = [0.2, -1.0, 0.1]
power = [1.0, 1.0, 1.0]

[receiver]
point = [0.0, {plane_y}, 0.0]
normal = [0.0, 1.0, 0.0]
albedo = [0.8, 0.8, 0.8]

[camera]
position = [0.3, 2.2, 1.4]
target = [0.15, -0.9, 0.05]
fov = 50
resolution = [240, 180]

[background]
type = "constant"
color = [0, 0, 0]
"#,
        c.x, c.y, c.z
    );
    let scene = Scene::parse(&text, "fig7").unwrap();
    let medium = Medium::build(&scene).unwrap();
    let regions = eikon_grid::Regions::new(&scene);
    let (volume, _) = eikon_wavefront::simulate_light_in(
        &scene.lights[0],
        &medium,
        Some(&regions),
        &eikon_wavefront::Options::default(),
        &|_, _| {},
    )
    .unwrap();
    let volumes = [volume];
    let env = load_environment(&scene.background).unwrap();
    let s = Surroundings::new(&scene, env, &volumes, &medium.geometry);
    let cam = camera(&scene);
    let img = Renderer::new(&medium, &volumes, &s, &cam, Options::default())
        .sharp(&scene)
        .render(&|_, _| {})
        .0;

    // Exact ray optics: rays across the sphere's disc, refracted in and
    // out, binned where they meet the plane.
    let d = DVec3::new(0.2, -1.0, 0.1).normalize();
    let lit = -d.y; // irradiance of the lit plane, W/m^2
    let cell = 0.004;
    let (lo, cells) = (-1.2, 600usize);
    let mut bins = vec![0.0f64; cells * cells];
    let e1 = d.cross(DVec3::X).normalize();
    let e2 = d.cross(e1);
    let rays = 2400usize;
    // The cross-section per ray.
    let da = (2.0 * r / rays as f64).powi(2);
    // A ray leaving the sphere at `p` along `dir` with `power`, binned
    // where it meets the plane (if it goes down to it).
    let bin = |bins: &mut [f64], p: DVec3, dir: DVec3, power: f64| {
        // (A NaN direction, from a numerically total reflection, too.)
        if dir.y.is_nan() || dir.y >= 0.0 {
            return;
        }
        let q = p + dir * ((plane_y - p.y) / dir.y);
        let (u, v) = (((q.x - lo) / cell) as i64, ((q.z - lo) / cell) as i64);
        if (0..cells as i64).contains(&u) && (0..cells as i64).contains(&v) {
            bins[u as usize * cells + v as usize] += power;
        }
    };
    for i in 0..rays {
        for j in 0..rays {
            let (a, b) = (
                ((i as f64 + 0.5) / rays as f64 * 2.0 - 1.0) * r,
                ((j as f64 + 0.5) / rays as f64 * 2.0 - 1.0) * r,
            );
            if a * a + b * b >= r * r {
                continue;
            }
            // The beam's irradiance is 1 W/m^2 across it.
            let p1 = c + e1 * a + e2 * b - d * (r * r - a * a - b * b).sqrt();
            let n1 = (p1 - c) / r;
            let r1 = fresnel(-d.dot(n1), 1.0, n);
            bin(&mut bins, p1, d - n1 * (2.0 * d.dot(n1)), da * r1);
            // Inside, every hit of the surface lets `1 - R` out and reflects
            // `R` on (no total reflection: a sphere's inner incidence is
            // its refraction angle), until what is left is negligible or,
            // for the few rays that graze it and circle on, 100 times.
            let (mut p, mut t, mut power) = (p1, refract(d, n1, 1.0, n), da * (1.0 - r1));
            for _ in 0..100 {
                if power <= 1e-9 * da {
                    break;
                }
                let chord = -2.0 * (p - c).dot(t);
                p += t * chord;
                power *= (-sigma * chord).exp();
                let n2 = (p - c) / r;
                let r2 = fresnel(t.dot(n2), n, 1.0);
                bin(&mut bins, p, refract(t, -n2, n, 1.0), power * (1.0 - r2));
                t -= n2 * (2.0 * t.dot(n2));
                power *= r2;
            }
        }
    }
    let irradiance = |p: DVec3| -> f64 {
        // Direct light where the line towards the light misses the sphere.
        let oc = p - c;
        let s = -oc.dot(-d); // closest approach along the line to the light
        let blocked = s > 0.0 && oc.length_squared() - s * s < r * r;
        let (u, v) = (((p.x - lo) / cell) as usize, ((p.z - lo) / cell) as usize);
        let caustic = bins[u * cells + v] / (cell * cell);
        if blocked {
            caustic
        } else {
            lit + caustic
        }
    };
    let albedo = 0.8;
    let lit_radiance = albedo * lit / std::f64::consts::PI;
    let (mut dark_exact, mut dark_render, mut plane) = (0usize, 0usize, 0usize);
    for y in 0..cam.height() {
        for x in 0..cam.width() {
            let (o, dir) = cam.ray(x, y, 0, Options::default().seed);
            let oc = o - c;
            let b = oc.dot(dir);
            if b * b - (oc.length_squared() - r * r) > 0.0 {
                continue; // sees the sphere
            }
            if dir.y >= 0.0 {
                continue;
            }
            let p = o + dir * ((plane_y - o.y) / dir.y);
            if !(p.x.abs() < 1.0 && p.z.abs() < 1.0) {
                continue;
            }
            plane += 1;
            if irradiance(p) < 0.5 * lit {
                dark_exact += 1;
            }
            if (img.data[(y * cam.width() + x) as usize][1] as f64) < 0.5 * lit_radiance {
                dark_render += 1;
            }
        }
    }
    let rel = dark_render as f64 / dark_exact as f64 - 1.0;
    println!(
        "Fig. 7 shadow, sharp interfaces at 128^3: {dark_render} pixels darker than half the lit plane, exact ray optics {dark_exact} ({:+.2}%), of {plane} plane pixels",
        100.0 * rel
    );
    assert!(
        dark_exact > 500,
        "the shadow covers {dark_exact} pixels only"
    );
    assert!(
        rel.abs() <= TOL,
        "shadow {dark_render} px, exact {dark_exact} px"
    );
}

/// Snell's law in vector form (textbook), for the exact ray optics above:
/// unit `d` meets a surface whose unit normal `nrm` faces it.
fn refract(d: DVec3, nrm: DVec3, n1: f64, n2: f64) -> DVec3 {
    let eta = n1 / n2;
    let cos_i = -d.dot(nrm);
    let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
    d * eta + nrm * (eta * cos_i - k.max(0.0).sqrt())
}

/// With dispersion, an eye ray carries the three channels along one path
/// until it comes to matter whose index differs by channel, then goes on
/// as three. That only saves work: every pixel must be bitwise the one
/// each channel's own ray gives, with the light volumes' per-channel flux
/// looked up in fog, on the receiver and behind a clear achromatic block
/// the shared ray passes through. And it must save: fewer steps in all.
#[test]
fn channels_share_a_ray_until_it_disperses_bit_for_bit() {
    let text = r#"
[grid]
resolution = 32
min = [-1, -1, -1]
max = [1, 1, 1]
dispersion = true

[ambient]
extinction = [0.2, 0.2, 0.2]
albedo = [0.5, 0.5, 0.5]
g = 0.3

[[object]]
name = "prism of dispersing glass"
shape = { type = "sphere", center = [-0.3, 0.1, 0], radius = 0.4 }
index = [1.48, 1.5, 1.52]
extinction = [0.5, 1, 2]
albedo = [0.7, 0.7, 0.7]

[[object]]
name = "achromatic block"
shape = { type = "box", center = [0.45, -0.05, 0], size = [0.5, 0.7, 0.6] }
index = 1.3
"#
    .to_owned()
        + &eikon_testkit::scenes::point_lit_floor([40, 30], 2);
    let (scene, medium, volumes) = eikon_testkit::scenes::lit(&text);
    assert_eq!(scene.grid.interfaces, eikon_grid::Interfaces::Sharp);
    assert!(volumes.iter().all(|v| v.flux.len() == 3));
    let env = load_environment(&scene.background).unwrap();
    let s = Surroundings::new(&scene, env, &volumes, &medium.geometry);
    let cam = camera(&scene);
    let renderer = || Renderer::new(&medium, &volumes, &s, &cam, Options::default()).sharp(&scene);
    let (shared, shared_stats) = renderer().render(&|_, _| {});
    let (apart, apart_stats) = renderer().channels_apart().render(&|_, _| {});
    let work = |s: eikon_view::Stats| s.steps + s.skips;
    println!(
        "shared ray: {} steps and skips, one ray per channel: {}",
        work(shared_stats),
        work(apart_stats)
    );
    // Something is lit, and the channels differ (the light and the
    // glass are coloured), so a mix-up of channels would show.
    assert!(shared.data.iter().any(|p| p[0] > 0.0 && p[0] != p[2]));
    for (i, (a, b)) in shared.data.iter().zip(&apart.data).enumerate() {
        assert_eq!(
            a.map(f32::to_bits),
            b.map(f32::to_bits),
            "pixel {i}: shared {a:?}, apart {b:?}"
        );
    }
    assert!(work(shared_stats) < work(apart_stats));
}
