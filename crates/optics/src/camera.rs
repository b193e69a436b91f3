//! Look-at pinhole camera and stratified, counter-hashed pixel sampling.
//!
//! # Conventions
//!
//! * World space is right-handed. The camera looks along
//!   `forward = normalize(target - position)`; `right = normalize(forward ×
//!   up)` and the true up is `right × forward`. With the common choice
//!   `up = +y` and `forward = -z` this makes `right = +x`.
//! * Image coordinates: pixel `(0, 0)` is the **top-left** pixel, `x` grows to
//!   the right and **`y` grows downwards** (the order in which PNG and EXR
//!   store rows). Pixel `(px, py)` covers the continuous square `[px, px + 1) ×
//!   [py, py + 1)`; its centre is `(px + 0.5, py + 0.5)`.
//! * `fov_y_degrees` is the full vertical field of view: the ray through the
//!   middle of the top image edge makes the angle `fov_y / 2` with `forward`.
//!   Pixels are square, so the horizontal field of view follows from the
//!   aspect ratio `width / height`.
//! * All rays of a pixel start at `position` (a pinhole has no aperture).
//!
//! # Sampling
//!
//! Sample `s` of a pixel is placed in its own stratum of an `nx × ny` grid,
//! `nx = ceil(sqrt(spp))`, `ny = ceil(spp / nx)`, and jittered inside it.
//! When `nx * ny > spp` a few strata stay empty; which ones is chosen by a
//! per-pixel pseudo-random permutation of the strata, so that every stratum
//! is equally likely to be used and the estimator stays unbiased (filling the
//! grid in scan order would always leave the bottom-right strata empty and
//! bias the pixel towards its top). All randomness comes from a
//! counter-based hash of `(seed, px, py, sample)`: no generator state is
//! carried between calls, so a render is bit-identical however the pixels
//! are distributed over threads.

use eikon_rng::{mix, unit_f64, GOLDEN};
use glam::DVec3;

/// Largest number of samples per pixel accepted by [`Camera::new`].
///
/// The stratum permutation works on 32-bit indices; 2^24 leaves ample
/// headroom for the `nx × ny` grid and is far beyond any practical render.
pub const MAX_SAMPLES: u32 = 1 << 24;

/// Why a [`Camera`] could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// Width or height is zero.
    #[error("camera image must be at least 1x1 pixels, got {width}x{height}")]
    EmptyImage {
        /// Requested width in pixels.
        width: u32,
        /// Requested height in pixels.
        height: u32,
    },
    /// The vertical field of view is not strictly between 0 and 180 degrees.
    #[error("camera vertical field of view must be in (0, 180) degrees, got {0}")]
    FieldOfView(f64),
    /// A position, target or up component is NaN or infinite.
    #[error("camera position, target and up must be finite")]
    NonFinite,
    /// `position == target`, so there is no view direction.
    #[error("camera position and target coincide; there is no view direction")]
    TargetAtPosition,
    /// `up` is zero or parallel to the view direction, so the roll is undefined.
    #[error("camera up vector is zero or parallel to the view direction")]
    UpParallel,
    /// Zero samples per pixel, or more than [`MAX_SAMPLES`].
    #[error("camera samples per pixel must be in 1..={max}, got {samples}")]
    Samples {
        /// Requested samples per pixel.
        samples: u32,
        /// The accepted maximum ([`MAX_SAMPLES`]).
        max: u32,
    },
}

/// A validated look-at pinhole camera (see the [module docs](self) for axes).
///
/// Fields are private so that a `Camera` is always valid; read them with the
/// accessors.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    position: DVec3,
    target: DVec3,
    up: DVec3,
    fov_y_degrees: f64,
    width: u32,
    height: u32,
    samples: u32,
    // Derived orthonormal basis and image-plane half extents at distance 1,
    // cached because `ray` is called once per sample.
    forward: DVec3,
    right: DVec3,
    true_up: DVec3,
    half_width: f64,
    half_height: f64,
    grid_x: u32,
    grid_y: u32,
}

impl Camera {
    /// Builds a camera at `position` looking at `target`, with `up` fixing the
    /// roll (it need not be orthogonal to the view direction, nor unit length).
    ///
    /// `fov_y_degrees` is the full vertical field of view, `width × height` the
    /// image size in pixels, `samples` the number of samples per pixel.
    ///
    /// # Errors
    ///
    /// [`CameraError`] if the size is zero, the field of view is not in
    /// (0, 180), a vector is not finite, `position == target`, `up` is zero or
    /// (within 1e-9 rad) parallel to the view direction, or `samples` is not in
    /// `1..=MAX_SAMPLES`.
    pub fn new(
        position: DVec3,
        target: DVec3,
        up: DVec3,
        fov_y_degrees: f64,
        width: u32,
        height: u32,
        samples: u32,
    ) -> Result<Camera, CameraError> {
        if width == 0 || height == 0 {
            return Err(CameraError::EmptyImage { width, height });
        }
        // `!(a < x && x < b)` also rejects NaN.
        if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
            return Err(CameraError::FieldOfView(fov_y_degrees));
        }
        if !(position.is_finite() && target.is_finite() && up.is_finite()) {
            return Err(CameraError::NonFinite);
        }
        if samples == 0 || samples > MAX_SAMPLES {
            return Err(CameraError::Samples {
                samples,
                max: MAX_SAMPLES,
            });
        }
        let view = target - position;
        // `normalize_or_zero` also guards against a difference that
        // underflows or overflows in the length computation.
        let forward = view.normalize_or_zero();
        if forward == DVec3::ZERO {
            return Err(CameraError::TargetAtPosition);
        }
        let up_unit = up.normalize_or_zero();
        let cross = forward.cross(up_unit);
        // |forward × up| = sin(angle); below 1e-9 the roll is numerically
        // meaningless.
        if up_unit == DVec3::ZERO || cross.length() < 1e-9 {
            return Err(CameraError::UpParallel);
        }
        let right = cross.normalize();
        let true_up = right.cross(forward);
        let half_height = (0.5 * fov_y_degrees).to_radians().tan();
        let half_width = half_height * f64::from(width) / f64::from(height);
        let (grid_x, grid_y) = strata_grid(samples);
        Ok(Camera {
            position,
            target,
            up,
            fov_y_degrees,
            width,
            height,
            samples,
            forward,
            right,
            true_up,
            half_width,
            half_height,
            grid_x,
            grid_y,
        })
    }

    /// Eye position; the origin of every ray.
    pub fn position(&self) -> DVec3 {
        self.position
    }

    /// The point the camera looks at.
    pub fn target(&self) -> DVec3 {
        self.target
    }

    /// The `up` vector as given to [`Camera::new`] (not orthogonalized).
    pub fn up(&self) -> DVec3 {
        self.up
    }

    /// Full vertical field of view in degrees.
    pub fn fov_y_degrees(&self) -> f64 {
        self.fov_y_degrees
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Samples per pixel.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Unit view direction, `normalize(target - position)`.
    pub fn forward(&self) -> DVec3 {
        self.forward
    }

    /// Unit vector pointing to the image's right (+x in image coordinates).
    pub fn right(&self) -> DVec3 {
        self.right
    }

    /// Unit vector pointing to the image's top (−y in image coordinates),
    /// orthogonal to [`forward`](Self::forward).
    pub fn true_up(&self) -> DVec3 {
        self.true_up
    }

    /// The stratification grid `(nx, ny)` used for this camera's samples per
    /// pixel; `nx * ny >= samples`.
    pub fn strata(&self) -> (u32, u32) {
        (self.grid_x, self.grid_y)
    }

    /// Ray through the continuous image point `(x, y)` (pixel units, origin at
    /// the top-left image corner, `y` down). Returns `(origin, unit direction)`.
    ///
    /// Points outside `[0, width] × [0, height]` are not rejected: they give
    /// the rays of the extended image plane, which is harmless and avoids a
    /// failure path in the hot loop.
    pub fn ray_through(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        let ndc_x = 2.0 * x / f64::from(self.width) - 1.0;
        // Image y grows downwards, world up is the opposite way.
        let ndc_y = 1.0 - 2.0 * y / f64::from(self.height);
        let dir = self.forward
            + self.right * (ndc_x * self.half_width)
            + self.true_up * (ndc_y * self.half_height);
        (self.position, dir.normalize())
    }

    /// Ray through the centre of pixel `(px, py)`, without jitter.
    pub fn center_ray(&self, px: u32, py: u32) -> (DVec3, DVec3) {
        self.ray_through(f64::from(px) + 0.5, f64::from(py) + 0.5)
    }

    /// Sub-pixel offset in `[0, 1)²` of sample `sample` of pixel `(px, py)`
    /// (the offset that [`ray`](Self::ray) uses).
    ///
    /// Samples `0..samples` occupy distinct strata (see the module docs).
    /// Indices beyond `samples` start new, independently permuted and
    /// jittered rounds (`round = sample / samples`), so progressive
    /// rendering with more than `samples` samples keeps working.
    pub fn sample_offset(&self, px: u32, py: u32, sample: u32, seed: u64) -> (f64, f64) {
        let round = sample / self.samples;
        let index = sample % self.samples;
        let cells = self.grid_x * self.grid_y;
        // One permutation key per pixel and round: the same key for all
        // samples of the round, so they map to distinct strata.
        let key = hash_words(&[seed, u64::from(px), u64::from(py), u64::from(round), 0]);
        let cell = permute(index, cells, key as u32);
        let (cx, cy) = (cell % self.grid_x, cell / self.grid_x);
        let jitter = hash_words(&[seed, u64::from(px), u64::from(py), u64::from(sample), 1]);
        let ju = unit_f64(jitter);
        let jv = unit_f64(mix(jitter ^ 0x6a09_e667_f3bc_c909));
        // `(c + j) / n` can round up to exactly 1.0 for j close to 1; clamp
        // to the largest double below 1 so the point stays in its pixel.
        let below_one = f64::from_bits(1.0f64.to_bits() - 1);
        let u = ((f64::from(cx) + ju) / f64::from(self.grid_x)).min(below_one);
        let v = ((f64::from(cy) + jv) / f64::from(self.grid_y)).min(below_one);
        (u, v)
    }

    /// Jittered, stratified ray for sample `sample` of pixel `(px, py)`.
    /// Returns `(origin, unit direction)`.
    ///
    /// The result depends only on the arguments (and the camera), never on
    /// call order or threads; `seed` selects an independent sample pattern
    /// (e.g. one per frame or per render).
    pub fn ray(&self, px: u32, py: u32, sample: u32, seed: u64) -> (DVec3, DVec3) {
        let (u, v) = self.sample_offset(px, py, sample, seed);
        self.ray_through(f64::from(px) + u, f64::from(py) + v)
    }
}

/// `(nx, ny)` with `nx = ceil(sqrt(n))`, `ny = ceil(n / nx)`: the most square
/// grid with at least `n` cells and fewer than `nx` empty ones.
fn strata_grid(n: u32) -> (u32, u32) {
    let mut nx = f64::from(n).sqrt().ceil() as u32;
    // Guard the float square root against off-by-one rounding.
    while nx > 1 && (nx - 1) * (nx - 1) >= n {
        nx -= 1;
    }
    while nx * nx < n {
        nx += 1;
    }
    let ny = n.div_ceil(nx);
    (nx, ny)
}

/// Hash of a word sequence, absorbing one word per splitmix64 round
/// ([`eikon_rng::mix`]); the golden-ratio increment keeps all-zero inputs
/// from hashing to zero.
fn hash_words(words: &[u64]) -> u64 {
    words
        .iter()
        .fold(GOLDEN, |h, &w| mix(h.wrapping_add(GOLDEN) ^ w))
}

/// Pseudo-random permutation of `0..len` evaluated at `i` (Kensler 2013,
/// "Correlated Multi-Jittered Sampling", with cycle walking so that any
/// `len >= 1` works). Each step is a bijection on the low bits selected by
/// the mask, so values outside `0..len` are walked until they fall inside.
fn permute(mut i: u32, len: u32, p: u32) -> u32 {
    if len <= 1 {
        return 0;
    }
    let mut w = len - 1;
    w |= w >> 1;
    w |= w >> 2;
    w |= w >> 4;
    w |= w >> 8;
    w |= w >> 16;
    loop {
        i ^= p;
        i = i.wrapping_mul(0xe170_893d);
        i ^= p >> 16;
        i ^= (i & w) >> 4;
        i ^= p >> 8;
        i = i.wrapping_mul(0x0929_eb3f);
        i ^= p >> 23;
        i ^= (i & w) >> 1;
        i = i.wrapping_mul(1 | (p >> 27));
        i = i.wrapping_mul(0x6935_fa69);
        i ^= (i & w) >> 11;
        i = i.wrapping_mul(0x74dc_b303);
        i ^= (i & w) >> 2;
        i = i.wrapping_mul(0x9e50_1cc3);
        i ^= (i & w) >> 2;
        i = i.wrapping_mul(0xc860_a3df);
        i &= w;
        i ^= i >> 5;
        if i < len {
            break;
        }
    }
    // The final rotation by `p` does not break bijectivity.
    ((u64::from(i) + u64::from(p)) % u64::from(len)) as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    fn cam(width: u32, height: u32, fov: f64, samples: u32) -> Camera {
        Camera::new(
            DVec3::new(0.3, -1.2, 4.0),
            DVec3::new(-0.5, 0.4, -0.7),
            DVec3::new(0.1, 1.0, 0.2),
            fov,
            width,
            height,
            samples,
        )
        .unwrap()
    }

    fn angle(a: DVec3, b: DVec3) -> f64 {
        // atan2 form: accurate also for small angles.
        a.cross(b).length().atan2(a.dot(b))
    }

    /// Projects a direction back onto the image plane: continuous (x, y).
    fn project(c: &Camera, d: DVec3) -> (f64, f64) {
        let d = d / d.dot(c.forward());
        let a = d.dot(c.right()) / c.half_width;
        let b = d.dot(c.true_up()) / c.half_height;
        (
            (a + 1.0) * 0.5 * f64::from(c.width()),
            (1.0 - b) * 0.5 * f64::from(c.height()),
        )
    }

    #[test]
    fn centre_pixel_of_odd_image_looks_at_target() {
        for (w, h) in [(1, 1), (5, 3), (101, 51), (7, 99)] {
            let c = cam(w, h, 40.0, 4);
            let (o, d) = c.center_ray(w / 2, h / 2);
            assert_eq!(o, c.position());
            let want = (c.target() - c.position()).normalize();
            assert!((d - want).length() < 1e-12, "{w}x{h}: {d} vs {want}");
        }
    }

    #[test]
    fn edge_and_corner_rays_span_the_field_of_view() {
        for (w, h, fov) in [(64, 48, 60.0), (33, 17, 90.0), (10, 40, 1.0), (8, 8, 170.0)] {
            let c = cam(w, h, fov, 1);
            let half = (0.5 * fov).to_radians();
            let aspect = f64::from(w) / f64::from(h);
            let (fw, fh) = (f64::from(w), f64::from(h));
            // Middle of the top and bottom edges: half the vertical fov.
            let (_, top) = c.ray_through(0.5 * fw, 0.0);
            let (_, bottom) = c.ray_through(0.5 * fw, fh);
            assert!((angle(top, c.forward()) - half).abs() < 1e-12);
            assert!((angle(bottom, c.forward()) - half).abs() < 1e-12);
            // Top is up, bottom is down (image y grows downwards).
            assert!(top.dot(c.true_up()) > 0.0 && bottom.dot(c.true_up()) < 0.0);
            // Left/right edges: horizontal half-angle from the aspect ratio.
            let half_x = (aspect * half.tan()).atan();
            let (_, left) = c.ray_through(0.0, 0.5 * fh);
            let (_, right) = c.ray_through(fw, 0.5 * fh);
            assert!((angle(left, c.forward()) - half_x).abs() < 1e-12);
            assert!(left.dot(c.right()) < 0.0 && right.dot(c.right()) > 0.0);
            // Corner: the diagonal of the image plane.
            let diag = ((1.0 + aspect * aspect).sqrt() * half.tan()).atan();
            let (_, corner) = c.ray_through(0.0, 0.0);
            assert!((angle(corner, c.forward()) - diag).abs() < 1e-12);
        }
    }

    #[test]
    fn axes_match_the_documented_convention() {
        // up = +y, looking down -z: right must be +x.
        let c = Camera::new(DVec3::ZERO, -DVec3::Z, DVec3::Y, 45.0, 4, 4, 1).unwrap();
        assert!((c.right() - DVec3::X).length() < 1e-15);
        assert!((c.true_up() - DVec3::Y).length() < 1e-15);
        // Pixel (0, 0) is top-left: up and to the left.
        let (_, d) = c.center_ray(0, 0);
        assert!(d.x < 0.0 && d.y > 0.0 && d.z < 0.0);
    }

    #[test]
    fn rays_are_deterministic_and_seed_dependent() {
        let c = cam(16, 9, 50.0, 8);
        let all = |seed: u64| -> Vec<(DVec3, DVec3)> {
            (0..16 * 9 * 8)
                .map(|k| c.ray(k % 16, (k / 16) % 9, k / 144, seed))
                .collect()
        };
        let a = all(7);
        // Compute the same rays in reverse order on other threads.
        let b: Vec<_> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..4u32)
                .map(|t| {
                    let c = &c;
                    s.spawn(move || {
                        (0..16 * 9 * 8u32)
                            .rev()
                            .filter(|k| k % 4 == t)
                            .map(|k| (k, c.ray(k % 16, (k / 16) % 9, k / 144, 7)))
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            let mut v = vec![(DVec3::ZERO, DVec3::ZERO); 16 * 9 * 8];
            for h in handles {
                for (k, r) in h.join().unwrap() {
                    v[k as usize] = r;
                }
            }
            v
        });
        assert_eq!(a, b);
        let other = all(8);
        let same = a.iter().zip(&other).filter(|(x, y)| x == y).count();
        assert_eq!(same, 0, "a different seed must move every sample");
        // Different samples of one pixel differ.
        let s: HashSet<_> = (0..8)
            .map(|i| c.ray(3, 4, i, 7).1.to_array().map(f64::to_bits))
            .collect();
        assert_eq!(s.len(), 8);
    }

    #[test]
    fn samples_stay_in_their_pixel_and_use_distinct_strata() {
        for spp in [1, 2, 3, 4, 5, 6, 7, 9, 10, 12, 16, 17, 50, 64, 257] {
            let c = cam(7, 5, 35.0, spp);
            let (nx, ny) = c.strata();
            assert!(nx * ny >= spp && nx * ny - spp < nx, "spp {spp}: {nx}x{ny}");
            for (px, py) in [(0, 0), (6, 4), (3, 2)] {
                let mut strata = HashSet::new();
                for s in 0..spp {
                    let (u, v) = c.sample_offset(px, py, s, 99);
                    assert!((0.0..1.0).contains(&u) && (0.0..1.0).contains(&v));
                    let cell = ((u * f64::from(nx)) as u32, (v * f64::from(ny)) as u32);
                    assert!(strata.insert(cell), "spp {spp}: stratum {cell:?} reused");
                    // The ray itself pierces the image plane inside the pixel.
                    let (_, d) = c.ray(px, py, s, 99);
                    let (x, y) = project(&c, d);
                    let (fx, fy) = (f64::from(px), f64::from(py));
                    assert!(x > fx - 1e-9 && x < fx + 1.0 + 1e-9, "x {x} px {px}");
                    assert!(y > fy - 1e-9 && y < fy + 1.0 + 1e-9, "y {y} py {py}");
                    assert!((x - fx - u).abs() < 1e-9 && (y - fy - v).abs() < 1e-9);
                }
                if nx * ny == spp {
                    assert_eq!(strata.len() as u32, nx * ny, "every stratum once");
                }
            }
        }
    }

    #[test]
    fn incomplete_grids_use_every_stratum_equally_often() {
        // spp = 3 on a 2x2 grid: each stratum must be used in 3/4 of the
        // pixels, otherwise the pixel estimate is biased to part of the pixel.
        let c = cam(64, 64, 35.0, 3);
        assert_eq!(c.strata(), (2, 2));
        let mut counts = [0u32; 4];
        for py in 0..64 {
            for px in 0..64 {
                for s in 0..3 {
                    let (u, v) = c.sample_offset(px, py, s, 5);
                    counts[(u * 2.0) as usize + 2 * (v * 2.0) as usize] += 1;
                }
            }
        }
        // Expected 3072 per stratum; binomial sd ~ 28.
        for n in counts {
            assert!((n as f64 - 3072.0).abs() < 150.0, "{counts:?}");
        }
        // The mean offset is the pixel centre.
        let n = 64 * 64 * 3;
        let (mut su, mut sv) = (0.0, 0.0);
        for k in 0..n {
            let (u, v) = c.sample_offset(k % 64, (k / 64) % 64, k / 4096, 5);
            su += u;
            sv += v;
        }
        assert!((su / f64::from(n) - 0.5).abs() < 0.01);
        assert!((sv / f64::from(n) - 0.5).abs() < 0.01);
    }

    #[test]
    fn later_rounds_are_stratified_too() {
        let c = cam(3, 3, 35.0, 4);
        let mut strata = HashSet::new();
        for s in 4..8 {
            let (u, v) = c.sample_offset(1, 1, s, 3);
            assert!(strata.insert(((u * 2.0) as u32, (v * 2.0) as u32)));
        }
        assert_ne!(c.sample_offset(1, 1, 0, 3), c.sample_offset(1, 1, 4, 3));
    }

    #[test]
    fn permutation_is_a_bijection() {
        for len in [1, 2, 3, 5, 16, 17, 100, 1000] {
            for key in [0, 1, 0xdead_beef, u32::MAX] {
                let s: HashSet<u32> = (0..len).map(|i| permute(i, len, key)).collect();
                assert_eq!(s.len() as u32, len);
                assert!(s.iter().all(|&x| x < len));
            }
        }
    }

    #[test]
    fn invalid_cameras_are_rejected() {
        let (p, t, u) = (DVec3::ZERO, -DVec3::Z, DVec3::Y);
        let e = |r: Result<Camera, CameraError>| r.unwrap_err();
        assert_eq!(
            e(Camera::new(p, t, u, 45.0, 0, 4, 1)),
            CameraError::EmptyImage {
                width: 0,
                height: 4
            }
        );
        assert!(matches!(
            e(Camera::new(p, t, u, 45.0, 4, 0, 1)),
            CameraError::EmptyImage { .. }
        ));
        for fov in [0.0, 180.0, -10.0, 200.0, f64::NAN] {
            assert!(matches!(
                e(Camera::new(p, t, u, fov, 4, 4, 1)),
                CameraError::FieldOfView(_)
            ));
        }
        assert_eq!(
            e(Camera::new(p, p, u, 45.0, 4, 4, 1)),
            CameraError::TargetAtPosition
        );
        assert_eq!(
            e(Camera::new(p, t, DVec3::Z, 45.0, 4, 4, 1)),
            CameraError::UpParallel
        );
        assert_eq!(
            e(Camera::new(p, t, DVec3::ZERO, 45.0, 4, 4, 1)),
            CameraError::UpParallel
        );
        assert_eq!(
            e(Camera::new(p, DVec3::NAN, u, 45.0, 4, 4, 1)),
            CameraError::NonFinite
        );
        assert!(matches!(
            e(Camera::new(p, t, u, 45.0, 4, 4, 0)),
            CameraError::Samples { samples: 0, .. }
        ));
        assert!(matches!(
            e(Camera::new(p, t, u, 45.0, 4, 4, MAX_SAMPLES + 1)),
            CameraError::Samples { .. }
        ));
        assert!(Camera::new(p, t, u, 45.0, 4, 4, MAX_SAMPLES).is_ok());
    }

    #[test]
    fn strata_grid_is_near_square() {
        for n in 1..2000u32 {
            let (nx, ny) = strata_grid(n);
            assert!(nx * ny >= n && (nx - 1) * ny < n);
            assert_eq!(nx, f64::from(n).sqrt().ceil() as u32);
        }
        let (nx, ny) = strata_grid(MAX_SAMPLES);
        assert_eq!((nx, ny), (4096, 4096));
    }
}
