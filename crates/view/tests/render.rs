//! The view renderer against analytic truth (issue: view renderer).
//!
//! `cargo test --release --test render -- --nocapture` prints the measured
//! errors.

use eikon_grid::ray::{trace, TraceOptions};
use eikon_grid::{AnalyticField, Form, Integrator, Medium, Scene};
use eikon_optics::{hg, Camera, Image};
use eikon_testkit::scenes::{camera, lit, point_lit_floor};
use eikon_view::background::load_environment;
use eikon_view::{Options, Renderer, Surroundings};
use eikon_wavefront::LightVolume;
use glam::DVec3;

/// Render with `opts`; also returns the camera.
fn render(
    scene: &Scene,
    medium: &Medium,
    volumes: &[LightVolume],
    opts: Options,
) -> (Image, Camera) {
    let env = load_environment(&scene.background).unwrap();
    let s = Surroundings::new(scene, env, volumes, &medium.geometry);
    let cam = camera(scene);
    let (img, _) = Renderer::new(medium, volumes, &s, &cam, opts).render(&|_, _| {});
    (img, cam)
}

/// The radiance law: an emitting slab of glass (n = 1.5) seen at normal
/// incidence against black. Radiance over n^2 is what a ray carries, so the
/// emission integrated through the slab, `L_e d`, reaches the eye in air
/// as `(1 - R) L_e d / n^2`: Fresnel transmission at the near face and the
/// 1/n^2 of leaving the glass. (Inside the smoothed interface bands n
/// passes through lower values, which reads a little high: the fine grid
/// keeps the bands to a small part of the path.) The same slab with n = 1 shows `L_e d`.
#[test]
fn radiance_leaving_glass_is_divided_by_n_squared() {
    let text = r#"
[grid]
resolution = 96
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "box", center = [0, 0, 0], size = [3, 3, 1.2] }
index = 1.5
extinction = [1e-6, 1e-6, 1e-6]
emission = [1, 1, 1]

[camera]
position = [0, 0, 40]
target = [0, 0, 0]
fov = 0.5
resolution = [5, 5]

[background]
type = "constant"
color = [0, 0, 0]
"#;
    let got = |t: &str| {
        let (scene, medium, volumes) = lit(t);
        let (img, _) = render(&scene, &medium, &volumes, Options::default());
        img.pixel(2, 2).unwrap()[1] as f64
    };
    let air = got(&text.replace("index = 1.5", "index = 1.0"));
    let glass = got(text);
    let r = ((1.0f64 - 1.5) / (1.0 + 1.5)).powi(2);
    println!(
        "emitting slab: n = 1 gives {air:.5} (L_e d = 1.2), n = 1.5 gives {glass:.5}, (1 - R) L_e d / n^2 = {:.5}",
        (1.0 - r) * 1.2 / 2.25
    );
    assert!((air - 1.2).abs() < 1.2 * 5e-3, "{air}");
    let want = (1.0 - r) * 1.2 / 2.25;
    assert!((glass - want).abs() < want * 1e-2, "{glass} vs {want}");
}

/// Oblique reflection: looking down at 45 degrees onto a flat glass
/// surface (n = 1.5) under an emitting board high above, with nothing
/// below: the pixel is the board's radiance times the unpolarized Fresnel
/// reflectance at 45 degrees, looked up in the mirror direction.
#[test]
fn a_glass_surface_reflects_the_fresnel_fraction_at_45_degrees() {
    let text = r#"
[grid]
resolution = 48
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "box", center = [0, -1, 0], size = [4, 2, 4] }
index = 1.5

[camera]
position = [0, 20, 20]
target = [0, 0, 0]
fov = 0.5
resolution = [5, 5]

[background]
type = "checker"
point = [-50, 8, -50]
normal = [0, -1, 0]
square = 100
colors = [[1, 1, 1], [1, 1, 1]]
"#;
    let (scene, medium, volumes) = lit(text);
    let (img, _) = render(&scene, &medium, &volumes, Options::default());
    let want = eikon_optics::fresnel::reflectance(45f64.to_radians().cos(), 1.0, 1.5);
    let got = img.pixel(2, 2).unwrap()[1] as f64;
    println!("reflection at 45 degrees: {got:.5}, Fresnel R = {want:.5}");
    assert!((got / want - 1.0).abs() < 0.01, "{got} vs {want}");
}

/// The diffuse receiver, lit through the light volume by a directional
/// light in clear air, is a Lambertian plane: radiance
/// `albedo / pi * E cos(theta)` with `E` the beam's irradiance. One part of
/// the view sees the plane inside the grid (light volume), another outside
/// it (direct lighting): both must agree with the formula.
#[test]
fn the_receiver_is_lambertian_inside_and_outside_the_grid() {
    let text = r#"
[grid]
resolution = 32
min = [-1, -1, -1]
max = [1, 1, 1]

[[light]]
type = "directional"
direction = [0.3, -1, 0.2]
power = [2, 2, 2]

[receiver]
point = [0, -0.5, 0]
normal = [0, 1, 0]
albedo = [0.6, 0.6, 0.6]

[camera]
position = [0, 3, 0.01]
target = [0, -0.5, 0]
fov = 50
resolution = [21, 21]

[background]
type = "constant"
color = [0, 0, 0]
"#;
    let (scene, medium, _) = lit(text);
    // The light volume of the plane wave exactly (the simulation's own
    // accuracy is tested in tests/fluence.rs): fluence 2, flux 2 l.
    let l = DVec3::new(0.3, -1.0, 0.2).normalize();
    let [nx, ny, nz] = medium.geometry.dims;
    let fluence = ndarray::Array4::from_elem((nx, ny, nz, 3), 2.0f32);
    let flux = ndarray::Array4::from_shape_fn((nx, ny, nz, 3), |(_, _, _, c)| 2.0 * l[c] as f32);
    let volumes = vec![LightVolume::from_arrays(&medium.geometry, fluence, vec![flux]).unwrap()];
    let (img, cam) = render(&scene, &medium, &volumes, Options::default());
    let want = 0.6 / std::f64::consts::PI * 2.0 * (-l.y);
    let (mut inside, mut outside, mut worst) = (0, 0, 0.0f64);
    for y in 0..cam.height() {
        for x in 0..cam.width() {
            let (o, d) = cam.ray(x, y, 0, 0);
            let hit = o + d * ((-0.5 - o.y) / d.y);
            if medium.geometry.contains(hit) {
                inside += 1;
            } else {
                outside += 1;
            }
            let got = img.pixel(x, y).unwrap()[0] as f64;
            worst = worst.max((got / want - 1.0).abs());
        }
    }
    println!("receiver: {inside} pixels inside the grid, {outside} outside, worst relative error {worst:.2e}");
    assert!(inside > 50 && outside > 50);
    assert!(worst < 1e-3, "{worst}");
}

/// A homogeneous scattering medium filling the volume, lit from above by
/// a directional light, seen from the side: single scattering in closed
/// form, `L = int sigma_s p(l . -d) E0 exp(-sigma depth(x)) exp(-sigma t) dt`
/// along the eye ray (taken by fine quadrature), must match within 1%.
#[test]
fn a_scattering_slab_matches_single_scattering() {
    // Forward scattering, and isotropic (whose phase function needs no
    // light direction: `absorb_and_emit` reads none).
    for g in [0.4, 0.0] {
        scattering_slab(g);
    }
}

fn scattering_slab(g: f64) {
    let sigma = 1.2;
    let albedo = 0.8;
    let text = format!(
        r#"
[grid]
resolution = 48
min = [-1, -1, -1]
max = [1, 1, 1]

[ambient]
index = 1.0
extinction = [{sigma}, {sigma}, {sigma}]
albedo = [{albedo}, {albedo}, {albedo}]
g = {g}

[[light]]
type = "directional"
direction = [0, -1, 0]
power = [2, 2, 2]

[camera]
position = [0.1, 0.05, 6]
target = [0, 0, 0]
fov = 12
resolution = [9, 9]

[background]
type = "constant"
color = [0, 0, 0]
"#
    );
    let (scene, medium, volumes) = lit(&text);
    let (img, cam) = render(&scene, &medium, &volumes, Options::default());
    // With exact interfaces the eye rays gather along straight pieces
    // through the uniform medium (`Renderer::trace_sharp`).
    let env = load_environment(&scene.background).unwrap();
    let s = Surroundings::new(&scene, env, &volumes, &medium.geometry);
    let (sharp, _) = Renderer::new(&medium, &volumes, &s, &cam, Options::default())
        .sharp(&scene)
        .render(&|_, _| {});
    let l = DVec3::new(0.0, -1.0, 0.0);
    let mut worst: f64 = 0.0;
    for (img, how) in [(&img, "smoothed"), (&sharp, "sharp")] {
        for (x, y) in [(4, 4), (0, 0), (8, 8), (2, 7), (7, 1)] {
            let (o, d) = cam.ray(x, y, 0, 0);
            let (t0, t1) = medium.geometry.clip_line(o, d).unwrap();
            let n = 20000;
            let dt = (t1 - t0) / n as f64;
            let mut want = 0.0;
            for k in 0..n {
                let t = t0 + (k as f64 + 0.5) * dt;
                let p = o + d * t;
                let e = 2.0 * (-sigma * (1.0 - p.y)).exp();
                want += albedo * sigma * hg(l.dot(-d), g) * e * (-sigma * (t - t0)).exp() * dt;
            }
            let got = img.pixel(x, y).unwrap()[0] as f64;
            let rel = (got - want).abs() / want;
            println!("scattering slab (g {g}, {how}), pixel ({x}, {y}): {got:.6} vs {want:.6}, relative {rel:.2e}");
            worst = worst.max(rel);
        }
    }
    assert!(worst < 0.01, "{worst}");
}

const LUNEBURG: &str = r#"
[grid]
resolution = 64
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = 0.8 }
index = { type = "luneburg" }

[camera]
position = [0.05, 0.1, 3.5]
target = [0, 0, 0]
fov = 30
resolution = [40, 40]

[render]
integrator = "rk4"
step = 0.25

[background]
type = "checker"
point = [0, 0, -1.2]
normal = [0, 0, 1]
square = 0.4
colors = [[1, 0, 0], [0, 0, 1]]
"#;

/// The checkerboard seen through a Luneburg lens: each pixel's colour is
/// predicted by tracing its ray through the exact (analytic) index field
/// and on to the board. Pixels whose predicted board point lies within a
/// tenth of a square of an edge, and rays through the smoothed rim, are not
/// judged.
#[test]
fn a_luneburg_lens_images_the_checkerboard_as_the_ray_map_predicts() {
    let (scene, medium, volumes) = lit(LUNEBURG);
    let (img, cam) = render(&scene, &medium, &volumes, Options::default());
    let field = AnalyticField::new(&scene, 0);
    let opts =
        TraceOptions::in_voxels(&medium.geometry, Form::EqualDistance, Integrator::Rk4, 0.05);
    let (square, board_z) = (0.4, -1.2);
    let (mut judged, mut agree, mut through_lens) = (0, 0, 0);
    for y in 0..cam.height() {
        for x in 0..cam.width() {
            let (o, d) = cam.ray(x, y, 0, 0);
            let end = trace(&field, &medium.geometry, o, d, &opts);
            let (p, u) = (end.position, end.direction);
            // The lens's rim is smoothed over about 3 voxels (0.09) either
            // side of r = 0.8 in the voxel field, not in the analytic one:
            // rays through that band are not judged.
            let b = o.cross(d).length();
            if u.z >= 0.0 || (0.7..0.9).contains(&b) {
                continue;
            }
            let q = p + u * ((board_z - p.z) / u.z);
            let (a, b) = (q.x / square, q.y / square);
            let edge = (a - a.round()).abs().min((b - b.round()).abs());
            if edge < 0.1 {
                continue;
            }
            let red = (a.floor() as i64 + b.floor() as i64).rem_euclid(2) == 0;
            let px = img.pixel(x, y).unwrap();
            judged += 1;
            if (px[0] > px[2]) == red {
                agree += 1;
            }
            if (end.direction - d).length() > 0.05 {
                through_lens += 1;
            }
        }
    }
    let frac = agree as f64 / judged as f64;
    println!(
        "Luneburg checkerboard: {agree} of {judged} judged pixels agree ({:.1}%), {through_lens} bent by the lens",
        100.0 * frac
    );
    assert!(through_lens > 200, "too few pixels see the lens");
    assert!(frac >= 0.97, "{frac}");
}

/// Dispersion: a sphere with n = 1.45, 1.5, 1.55 for R, G, B in front of a
/// black/white edge. Through the lens each channel sees the edge at its
/// own place along a scanline, in the order of its index, where a trace
/// of that channel's ray through its own index field predicts it.
#[test]
fn dispersion_separates_the_channels_in_index_order() {
    let text = r#"
[grid]
resolution = 64
min = [-1, -1, -1]
max = [1, 1, 1]
dispersion = true

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = 0.7 }
index = [1.45, 1.5, 1.55]

[camera]
position = [0, 0, 4]
target = [0, 0, 0]
# Vertical: 3 pixels of a 22-degree-wide row of 400.
fov = 0.167
resolution = [400, 3]

[background]
type = "checker"
point = [0.4, -50, -2]
normal = [0, 0, 1]
square = 100
colors = [[1, 1, 1], [0, 0, 0]]
"#;
    let (scene, medium, volumes) = lit(text);
    // RK4, so that what is compared is dispersion, not Euler's error.
    let opts = Options {
        integrator: Integrator::Rk4,
        step: 0.25,
        ..Options::default()
    };
    let (img, cam) = render(&scene, &medium, &volumes, opts);
    let opts = TraceOptions::in_voxels(&medium.geometry, Form::EqualDistance, Integrator::Rk4, 0.1);
    let mut seen = [0.0; 3];
    let mut predicted = [0.0; 3];
    for c in 0..3 {
        let field = medium.field(c);
        // First pixel from the left whose channel turns dark (the lens
        // inverts: its left side sees the bright right of the board).
        let row = 1;
        // Judge rays well inside the sphere only: at its rim Fresnel
        // reflection (near 1 at grazing) shows other parts of the board.
        let start = (0..cam.width())
            .find(|&x| {
                let (o, d) = cam.ray(x, row, 0, 0);
                o.cross(d).length() < 0.6
            })
            .unwrap();
        let first = |bright: &dyn Fn(u32) -> bool| (start..cam.width()).find(|&x| bright(x));
        seen[c] = first(&|x| img.pixel(x, row).unwrap()[c] < 0.5).unwrap() as f64;
        predicted[c] = first(&|x| {
            let (o, d) = cam.ray(x, row, 0, 0);
            let end = trace(&field, &medium.geometry, o, d, &opts);
            let q = end.position + end.direction * ((-2.0 - end.position.z) / end.direction.z);
            !(end.direction.z < 0.0 && q.x >= 0.4)
        })
        .unwrap() as f64;
    }
    println!("dispersion: edge seen at pixels {seen:?}, predicted {predicted:?}");
    for c in 0..3 {
        assert!(
            (seen[c] - predicted[c]).abs() <= 1.0,
            "{c}: {seen:?} vs {predicted:?}"
        );
    }
    let increasing = seen[0] < seen[1] && seen[1] < seen[2];
    // A higher index bends more: the inverted image of the edge reaches
    // further out, so red (the lowest index) turns dark first.
    assert!(increasing, "{seen:?}");
}

#[test]
fn images_are_identical_with_one_and_two_threads() {
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
shape = { type = "sphere", center = [0, 0.1, 0], radius = 0.5 }
index = [1.48, 1.5, 1.52]
extinction = [0.5, 1, 2]
albedo = [0.7, 0.7, 0.7]
emission = [0.1, 0, 0]
"#
    .to_owned()
        + &point_lit_floor([40, 30], 3);
    let (scene, medium, volumes) = lit(&text);
    let pool = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    let a = pool(1).install(|| render(&scene, &medium, &volumes, Options::default()).0);
    let b = pool(2).install(|| render(&scene, &medium, &volumes, Options::default()).0);
    assert!(a.data.iter().any(|p| p[0] > 0.0));
    assert!(a.data == b.data, "images differ between 1 and 2 threads");
}

/// A checkerboard lying on the grid's far face is seen through a uniform
/// medium alike whether the renderer skips empty space or steps through
/// it: a ray that reaches the face by a skip leaves there, and is not
/// stepped a hair beyond the board (which left a third of it black).
#[test]
fn a_board_on_the_grid_face_is_seen_with_and_without_skipping() {
    let text = r#"
[grid]
resolution = [80, 16, 40]
min = [-2.0, -0.2, -1.0]
max = [2.0, 0.6, 1.0]

[ambient]
index = 1.03

[camera]
position = [-1.9, 0.4, 0.0]
target = [2.0, 0.0, 0.0]
fov = 20
resolution = [64, 48]

[background]
type = "checker"
point = [2.0, 0.0, 0.0]
normal = [-1.0, 0.0, 0.0]
square = 0.1
colors = [[0.9, 0.55, 0.12], [0.1, 0.18, 0.45]]
"#;
    let (scene, medium, volumes) = lit(text);
    let opts = |skip_empty| Options {
        skip_empty,
        ..Options::default()
    };
    let (skip, _) = render(&scene, &medium, &volumes, opts(true));
    let (step, _) = render(&scene, &medium, &volumes, opts(false));
    let dark = |img: &Image| {
        (0..img.height)
            .flat_map(|y| (0..img.width).map(move |x| (x, y)))
            .filter(|&(x, y)| img.pixel(x, y).unwrap().iter().all(|&c| c < 0.05))
            .count()
    };
    let differ = (0..skip.height)
        .flat_map(|y| (0..skip.width).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let (a, b) = (skip.pixel(x, y).unwrap(), step.pixel(x, y).unwrap());
            (0..3).any(|c| (a[c] - b[c]).abs() > 0.05 * (a[c].abs() + b[c].abs()) + 1e-3)
        })
        .count();
    println!(
        "black pixels: {} skipping, {} stepping; {differ} of {} differ",
        dark(&skip),
        dark(&step),
        skip.width * skip.height
    );
    assert_eq!(dark(&step), 0, "every pixel sees the board when stepping");
    assert_eq!(dark(&skip), 0, "every pixel sees the board when skipping");
    assert_eq!(differ, 0, "pixels that differ");
}
