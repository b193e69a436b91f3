//! Distant background radiance `L_bg` ([Ihrke07 eq 1] and [Ihrke07 sec 5.3]):
//! after a view ray leaves the volume, its exit direction looks up an
//! environment map.
//!
//! # Latitude-longitude mapping
//!
//! World **+y is up**. A unit direction `d` maps to texture coordinates
//!
//! * `u = 0.5 + atan2(d.x, −d.z) / 2π` (longitude, in `[0, 1)`), and
//! * `v = acos(d.y) / π` (colatitude, in `[0, 1]`),
//!
//! so `v = 0` (the top row) is straight up (+y), `v = 1` (the bottom row)
//! straight down, and the horizon is the middle row. The map's centre
//! `u = 0.5` looks along **−z** (the default view direction of a camera with
//! `up = +y`), `u = 0.75` along +x, `u = 0.25` along −x, and the left/right
//! edges `u = 0 ≡ 1` along +z, where the longitude wraps. This matches the
//! usual layout of captured equirectangular panoramas, whose centre is
//! "straight ahead".
//!
//! Texel `(i, j)` (column `i`, row `j`, top row first) covers
//! `[i, i+1)/W × [j, j+1)/H` and is sampled at its centre
//! `((i + ½)/W, (j + ½)/H)`. Lookups filter bilinearly between the four
//! nearest texel centres, wrapping around in longitude and clamping in
//! latitude (at the poles the map row is the best available estimate).

use glam::DVec3;
use std::f64::consts::PI;
use std::io::Cursor;
use std::path::{Path, PathBuf};

/// Largest map accepted from a file, in texels (2^28 texels are 3 GiB of RGB
/// f32): refuses corrupt or hostile headers before allocating.
pub const MAX_TEXELS: usize = 1 << 28;

/// The largest EXR file read: [`MAX_TEXELS`] RGBA texels of 32-bit floats,
/// uncompressed, with room for the header.
pub const MAX_EXR_BYTES: u64 = (MAX_TEXELS as u64) * 16 + (1 << 20);

/// The most OpenEXR data is compressed: pixel bytes per file byte, with
/// room to spare (zip stops near 1032:1, PIZ's run-length Huffman codes
/// near 400:1, RLE and B44 far below).
pub const MAX_COMPRESSION: u64 = 4096;

/// Why an environment map could not be loaded or built.
#[derive(Debug, thiserror::Error)]
pub enum EnvironmentError {
    /// The file could not be read (missing, permissions, ...).
    #[error("{}: cannot read environment map", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The file does not start with the OpenEXR magic number.
    #[error("{}: not an OpenEXR file", path.display())]
    NotExr {
        /// The file.
        path: PathBuf,
    },
    /// No layer of the EXR file has all of the channels R, G and B.
    #[error(
        "{}: no layer with R, G and B channels (found channels: {found})",
        path.display()
    )]
    NoRgb {
        /// The file.
        path: PathBuf,
        /// The channel names of the file's layers, comma separated.
        found: String,
    },
    /// The map is larger than [`MAX_TEXELS`].
    #[error("{}: environment map of {width}x{height} texels is too large", path.display())]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Width in texels.
        width: usize,
        /// Height in texels.
        height: usize,
    },
    /// The header announces more texels than the file can hold, even
    /// compressed as well as OpenEXR compresses ([`MAX_COMPRESSION`]).
    #[error(
        "{}: a {width}x{height} texel image cannot be stored in {len} bytes: corrupt header",
        path.display()
    )]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// Width in texels.
        width: usize,
        /// Height in texels.
        height: usize,
        /// The file's size in bytes.
        len: usize,
    },
    /// The EXR decoder failed (corrupt or unsupported file).
    #[error("{}: cannot decode OpenEXR file", path.display())]
    Decode {
        /// The file.
        path: PathBuf,
        /// The decoder's error.
        #[source]
        source: exr::error::Error,
    },
    /// In-memory map data whose length does not match its size, or an empty
    /// map.
    #[error("environment map of {width}x{height} texels needs {} values, got {len}", width * height)]
    Size {
        /// Width in texels.
        width: usize,
        /// Height in texels.
        height: usize,
        /// Number of texels supplied.
        len: usize,
    },
}

/// Texture coordinates `(u, v)` of a direction (see the module docs for the
/// mapping). `d` need not be unit length. `u` is in `[0, 1)` and `v` in
/// `[0, 1]` for finite non-zero `d`; otherwise NaN.
pub fn uv_from_direction(d: DVec3) -> (f64, f64) {
    let len = d.length();
    if !(len > 0.0 && len.is_finite()) {
        return (f64::NAN, f64::NAN);
    }
    let d = d / len;
    let mut u = 0.5 + d.x.atan2(-d.z) / (2.0 * PI);
    // atan2 returns +π (not −π) for −0.0/+0.0 edge cases; fold u = 1 to 0 so
    // u stays in [0, 1).
    if u >= 1.0 {
        u -= 1.0;
    }
    let v = d.y.clamp(-1.0, 1.0).acos() / PI;
    (u, v)
}

/// Unit direction for texture coordinates `(u, v)`; the inverse of
/// [`uv_from_direction`].
pub fn direction_from_uv(u: f64, v: f64) -> DVec3 {
    let phi = (u - 0.5) * 2.0 * PI;
    let theta = v * PI;
    let (sin_t, cos_t) = theta.sin_cos();
    let (sin_p, cos_p) = phi.sin_cos();
    DVec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p)
}

/// An RGB latitude-longitude radiance map (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct LatLongMap {
    width: usize,
    height: usize,
    data: Vec<[f32; 3]>,
}

impl LatLongMap {
    /// A `width × height` map from row-major texels, top row (`v = 0`, +y)
    /// first.
    ///
    /// Non-finite and negative values are replaced by 0 so that one bad
    /// texel (common in captured HDR panoramas) cannot turn every filtered
    /// lookup near it into NaN or negative radiance.
    ///
    /// # Errors
    ///
    /// [`EnvironmentError::Size`] if a dimension is zero or
    /// `data.len() != width * height`.
    pub fn new(
        width: usize,
        height: usize,
        mut data: Vec<[f32; 3]>,
    ) -> Result<LatLongMap, EnvironmentError> {
        if width == 0 || height == 0 || width.checked_mul(height) != Some(data.len()) {
            return Err(EnvironmentError::Size {
                width,
                height,
                len: data.len(),
            });
        }
        for texel in &mut data {
            for c in texel.iter_mut() {
                if !(c.is_finite() && *c > 0.0) {
                    *c = 0.0;
                }
            }
        }
        Ok(LatLongMap {
            width,
            height,
            data,
        })
    }

    /// Width in texels (longitude).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in texels (latitude).
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row-major texels, top row first.
    pub fn data(&self) -> &[[f32; 3]] {
        &self.data
    }

    /// Texel at column `i`, row `j`, or `None` outside the map.
    pub fn texel(&self, i: usize, j: usize) -> Option<[f32; 3]> {
        (i < self.width && j < self.height).then(|| self.data[j * self.width + i])
    }

    /// Direction of the centre of texel `(i, j)`.
    pub fn texel_direction(&self, i: usize, j: usize) -> DVec3 {
        direction_from_uv(
            (i as f64 + 0.5) / self.width as f64,
            (j as f64 + 0.5) / self.height as f64,
        )
    }

    /// Bilinearly filtered radiance at texture coordinates `(u, v)`, wrapping
    /// `u` and clamping `v`. NaN coordinates give NaN.
    pub fn sample_uv(&self, u: f64, v: f64) -> [f64; 3] {
        if !(u.is_finite() && v.is_finite()) {
            return [f64::NAN; 3];
        }
        let (w, h) = (self.width as f64, self.height as f64);
        // Continuous texel coordinates with texel centres on integers.
        let x = u * w - 0.5;
        let y = (v * h - 0.5).clamp(0.0, h - 1.0);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        // rem_euclid wraps negative columns (u near 0) to the right edge.
        let i0 = (x0 as i64).rem_euclid(self.width as i64) as usize;
        let i1 = (i0 + 1) % self.width;
        let j0 = y0 as usize;
        let j1 = (j0 + 1).min(self.height - 1);
        let t = |i: usize, j: usize| self.data[j * self.width + i];
        let (a, b, c, d) = (t(i0, j0), t(i1, j0), t(i0, j1), t(i1, j1));
        std::array::from_fn(|k| {
            let top = f64::from(a[k]) * (1.0 - fx) + f64::from(b[k]) * fx;
            let bottom = f64::from(c[k]) * (1.0 - fx) + f64::from(d[k]) * fx;
            top * (1.0 - fy) + bottom * fy
        })
    }

    /// Reads the first layer with R, G and B channels (A and others are
    /// ignored) of an OpenEXR file, at its largest resolution level. Samples
    /// of any EXR type (f16, f32, u32) are converted to f32; see
    /// [`LatLongMap::new`] for the treatment of negative and non-finite
    /// values.
    ///
    /// # Errors
    ///
    /// An [`EnvironmentError`] naming the file: `Io` if it cannot be read,
    /// `NotExr` if it is not an OpenEXR file, `NoRgb` if no layer has R, G
    /// and B, `TooLarge` above [`MAX_TEXELS`], `Corrupt` when the header
    /// announces more texels than the file can hold, `Decode` if decoding
    /// fails.
    pub fn from_exr(path: impl AsRef<Path>) -> Result<LatLongMap, EnvironmentError> {
        let path = path.as_ref();
        let bytes = eikon_mesh::load::read_file(path, MAX_EXR_BYTES).map_err(|source| {
            EnvironmentError::Io {
                path: path.to_path_buf(),
                source,
            }
        })?;
        Self::from_exr_bytes(&bytes, path)
    }

    /// Like [`from_exr`](Self::from_exr) for a file already in memory;
    /// `path` is only used in error messages.
    ///
    /// # Errors
    ///
    /// As [`from_exr`](Self::from_exr), except `Io`.
    pub fn from_exr_bytes(bytes: &[u8], path: &Path) -> Result<LatLongMap, EnvironmentError> {
        use exr::prelude::*;
        let path_buf = || path.to_path_buf();
        // Classify the failure before decoding, so the message says what is
        // wrong instead of a decoder-internal "invalid" string.
        if !bytes.starts_with(&exr::meta::magic_number::BYTES) {
            return Err(EnvironmentError::NotExr { path: path_buf() });
        }
        let decode = |source| EnvironmentError::Decode {
            path: path_buf(),
            source,
        };
        let meta =
            exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(decode)?;
        let has = |h: &exr::meta::header::Header, name: &str| {
            h.channels.list.iter().any(|c| c.name == *name)
        };
        let Some(header) = meta
            .headers
            .iter()
            .find(|h| !h.deep && has(h, "R") && has(h, "G") && has(h, "B"))
        else {
            let found: Vec<String> = meta
                .headers
                .iter()
                .flat_map(|h| h.channels.list.iter().map(|c| c.name.to_string()))
                .collect();
            return Err(EnvironmentError::NoRgb {
                path: path_buf(),
                found: found.join(", "),
            });
        };
        let (width, height) = (header.layer_size.width(), header.layer_size.height());
        if width.checked_mul(height).is_none_or(|n| n > MAX_TEXELS) {
            return Err(EnvironmentError::TooLarge {
                path: path_buf(),
                width,
                height,
            });
        }
        // A header announcing far more pixels than the file can hold is
        // refused before the decoder allocates them (an 800-byte file
        // asking for 10289168 x 8 texels took seconds and a gigabyte).
        let pixel_bytes = (width as u64)
            .saturating_mul(height as u64)
            .saturating_mul(header.channels.bytes_per_pixel.max(1) as u64);
        if pixel_bytes > MAX_COMPRESSION.saturating_mul(bytes.len() as u64) {
            return Err(EnvironmentError::Corrupt {
                path: path_buf(),
                width,
                height,
                len: bytes.len(),
            });
        }
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .rgba_channels(
                |size, _| (size.width(), vec![[0.0f32; 3]; size.area()]),
                |(w, texels): &mut (usize, Vec<[f32; 3]>),
                 pos: Vec2<usize>,
                 (r, g, b, _a): (f32, f32, f32, f32)| {
                    texels[pos.y() * *w + pos.x()] = [r, g, b];
                },
            )
            .first_valid_layer()
            .all_attributes()
            // Decoding is single-threaded by choice (see Cargo.toml); ask
            // for it explicitly so that a workspace-wide `rayon` feature on
            // `exr` does not change behaviour.
            .non_parallel()
            .from_buffered(Cursor::new(bytes))
            .map_err(decode)?;
        let size = image.layer_data.size;
        let (_, texels) = image.layer_data.channel_data.pixels;
        LatLongMap::new(size.width(), size.height(), texels)
    }
}

/// Parameters of the procedural sky of [`Environment::sky_with`]: a sky
/// gradient from horizon to zenith, a uniform ground, and a soft sun. All
/// colours are linear RGB radiance.
#[derive(Debug, Clone, PartialEq)]
pub struct Sky {
    /// Radiance straight up.
    pub zenith: [f32; 3],
    /// Radiance of the sky at the horizon.
    pub horizon: [f32; 3],
    /// Radiance of the ground just below the horizon.
    pub ground: [f32; 3],
    /// Direction towards the sun (need not be unit length).
    pub sun_direction: DVec3,
    /// Peak radiance of the sun.
    pub sun_radiance: [f32; 3],
    /// Angular radius (standard deviation of the Gaussian lobe) of the sun,
    /// in degrees. The real sun's 0.27° would alias on a map of practical
    /// size; a few degrees gives soft, visible highlights.
    pub sun_radius_degrees: f64,
    /// Map width in texels (the height is half of it).
    pub width: usize,
}

impl Default for Sky {
    /// A clear blue sky with a warm sun at 30° elevation in front-right of
    /// a camera that looks along −z, above a grey-brown ground.
    fn default() -> Self {
        let elevation = 30f64.to_radians();
        let azimuth = 20f64.to_radians(); // from −z towards +x
        Sky {
            zenith: [0.25, 0.45, 0.95],
            horizon: [0.85, 0.9, 1.0],
            ground: [0.3, 0.27, 0.22],
            sun_direction: DVec3::new(
                elevation.cos() * azimuth.sin(),
                elevation.sin(),
                -elevation.cos() * azimuth.cos(),
            ),
            sun_radiance: [400.0, 370.0, 320.0],
            sun_radius_degrees: 2.0,
            width: 512,
        }
    }
}

impl Sky {
    /// Unfiltered radiance of the sky model in direction `d` (unit length).
    fn radiance(&self, d: DVec3, sun: DVec3) -> [f64; 3] {
        let lerp = |a: [f32; 3], b: [f32; 3], t: f64| -> [f64; 3] {
            std::array::from_fn(|k| f64::from(a[k]) * (1.0 - t) + f64::from(b[k]) * t)
        };
        let elevation = d.y.clamp(-1.0, 1.0).asin();
        // Sky brightens towards the horizon (sqrt keeps the blue high up).
        let sky = lerp(self.horizon, self.zenith, (d.y.max(0.0)).sqrt());
        // Ground darkens slightly towards the nadir.
        let ground = self
            .ground
            .map(|c| f64::from(c) * (1.0 - 0.4 * (-d.y).max(0.0)));
        // Blend across ±1.5° so the horizon does not alias.
        let blend = 1.5f64.to_radians();
        let t = ((elevation + blend) / (2.0 * blend)).clamp(0.0, 1.0);
        let t = t * t * (3.0 - 2.0 * t);
        let sigma = self.sun_radius_degrees.to_radians().max(1e-6);
        let angle = d.cross(sun).length().atan2(d.dot(sun));
        // The sun sets behind the ground: weight it by the same blend.
        let sun_w = (-(angle / sigma).powi(2) / 2.0).exp() * t;
        std::array::from_fn(|k| {
            ground[k] * (1.0 - t) + sky[k] * t + f64::from(self.sun_radiance[k]) * sun_w
        })
    }

    /// Renders the sky into a `width × width/2` lat-long map (width at least
    /// 4), sampling each texel at its centre.
    pub fn build(&self) -> Environment {
        let width = self.width.max(4);
        let height = width / 2;
        let sun = self.sun_direction.normalize_or(DVec3::Y);
        let mut data = Vec::with_capacity(width * height);
        for j in 0..height {
            for i in 0..width {
                let d = direction_from_uv(
                    (i as f64 + 0.5) / width as f64,
                    (j as f64 + 0.5) / height as f64,
                );
                data.push(self.radiance(d, sun).map(|c| c as f32));
            }
        }
        // Cannot fail: the size matches by construction and values are
        // finite, but avoid a panic path anyway.
        match LatLongMap::new(width, height, data) {
            Ok(map) => Environment::LatLong(map),
            Err(_) => Environment::Constant(self.horizon),
        }
    }
}

/// Background radiance seen in a direction.
#[derive(Debug, Clone, PartialEq)]
pub enum Environment {
    /// The same linear RGB radiance in every direction.
    Constant([f32; 3]),
    /// A latitude-longitude map (see the module docs).
    LatLong(LatLongMap),
}

impl Environment {
    /// Texels of its map: 0 for a constant one (for memory estimates).
    pub fn texels(&self) -> usize {
        match self {
            Environment::Constant(_) => 0,
            Environment::LatLong(m) => m.width() * m.height(),
        }
    }
}

impl Environment {
    /// Loads a lat-long map from an OpenEXR file; see
    /// [`LatLongMap::from_exr`].
    ///
    /// # Errors
    ///
    /// An [`EnvironmentError`] naming the file.
    pub fn from_exr(path: impl AsRef<Path>) -> Result<Environment, EnvironmentError> {
        LatLongMap::from_exr(path).map(Environment::LatLong)
    }

    /// The default procedural sky ([`Sky::default`]), for demos without
    /// files.
    pub fn sky() -> Environment {
        Sky::default().build()
    }

    /// A procedural sky with custom parameters.
    pub fn sky_with(sky: &Sky) -> Environment {
        sky.build()
    }

    /// Linear RGB radiance arriving from direction `dir` (the direction the
    /// view ray travels when it leaves the scene; need not be unit length).
    /// Lat-long maps are bilinearly filtered. A zero or non-finite direction
    /// gives NaN for maps (so that a broken ray shows up rather than being
    /// silently coloured); a constant environment ignores the direction.
    pub fn lookup(&self, dir: DVec3) -> [f64; 3] {
        match self {
            Environment::Constant(c) => c.map(f64::from),
            Environment::LatLong(map) => {
                let (u, v) = uv_from_direction(dir);
                map.sample_uv(u, v)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use exr::prelude::{SpecificChannels, WritableImage};

    fn close(a: [f64; 3], b: [f32; 3], tol: f64) -> bool {
        (0..3).all(|k| (a[k] - f64::from(b[k])).abs() <= tol * (1.0 + f64::from(b[k]).abs()))
    }

    /// A map whose texels are all different: r = i, g = j, b = i*j + 0.5.
    fn ramp(w: usize, h: usize) -> Vec<[f32; 3]> {
        (0..w * h)
            .map(|k| {
                let (i, j) = (k % w, k / w);
                [i as f32, j as f32 + 0.25, (i * j) as f32 + 0.5]
            })
            .collect()
    }

    fn write_exr(path: &Path, w: usize, h: usize, data: &[[f32; 3]]) {
        exr::prelude::write_rgb_file(path, w, h, |x, y| {
            let p = data[y * w + x];
            (p[0], p[1], p[2])
        })
        .unwrap();
    }

    #[test]
    fn constant_lookup_ignores_direction() {
        let env = Environment::Constant([0.5, 1.0, 2.0]);
        for d in [DVec3::X, -DVec3::Y, DVec3::new(1.0, 2.0, -3.0), DVec3::ZERO] {
            assert_eq!(env.lookup(d), [0.5, 1.0, 2.0]);
        }
    }

    #[test]
    fn mapping_follows_the_documented_axes() {
        let uv = |d: DVec3| uv_from_direction(d);
        assert_eq!(uv(DVec3::Y).1, 0.0);
        assert_eq!(uv(-DVec3::Y).1, 1.0);
        assert!((uv(-DVec3::Z).0 - 0.5).abs() < 1e-15 && (uv(-DVec3::Z).1 - 0.5).abs() < 1e-15);
        assert!((uv(DVec3::X).0 - 0.75).abs() < 1e-15);
        assert!((uv(-DVec3::X).0 - 0.25).abs() < 1e-15);
        assert_eq!(uv(DVec3::Z).0, 0.0);
        // Unnormalized input and the inverse mapping.
        for k in 0..200 {
            let d = DVec3::new(
                (k as f64 * 0.37).sin(),
                (k as f64 * 0.91).cos(),
                (k as f64 * 1.3).sin() - 0.2,
            );
            let (u, v) = uv(3.0 * d);
            assert!((0.0..1.0).contains(&u) && (0.0..=1.0).contains(&v));
            assert!((direction_from_uv(u, v) - d.normalize()).length() < 1e-12);
        }
        assert!(uv(DVec3::ZERO).0.is_nan());
    }

    #[test]
    fn exr_round_trip_is_exact_at_texel_centres() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("map.exr");
        let (w, h) = (8, 5);
        let data = ramp(w, h);
        write_exr(&path, w, h, &data);
        let env = Environment::from_exr(&path).unwrap();
        let Environment::LatLong(map) = &env else {
            panic!("expected a lat-long map")
        };
        assert_eq!((map.width(), map.height()), (w, h));
        assert_eq!(map.data(), &data[..]);
        for j in 0..h {
            for i in 0..w {
                // Looking towards a texel centre returns that texel.
                let got = env.lookup(map.texel_direction(i, j));
                assert!(close(got, data[j * w + i], 1e-9), "{i},{j}: {got:?}");
            }
        }
    }

    #[test]
    fn bilinear_between_centres_and_across_the_seam() {
        let (w, h) = (6, 4);
        let data = ramp(w, h);
        let map = LatLongMap::new(w, h, data.clone()).unwrap();
        let px = |i: usize, j: usize| data[j * w + i].map(f64::from);
        // Halfway between texels (1, 2) and (2, 2).
        let mid = map.sample_uv(2.0 / w as f64, 2.5 / h as f64);
        let want: [f64; 3] = std::array::from_fn(|k| 0.5 * (px(1, 2)[k] + px(2, 2)[k]));
        assert!(close(mid, want.map(|c| c as f32), 1e-12));
        // u = 0 lies halfway between the last and the first column.
        let seam = map.sample_uv(0.0, 1.5 / h as f64);
        let want: [f64; 3] = std::array::from_fn(|k| 0.5 * (px(w - 1, 1)[k] + px(0, 1)[k]));
        assert!(close(seam, want.map(|c| c as f32), 1e-12));
        // Continuity: just either side of the seam agree.
        let env = Environment::LatLong(map.clone());
        let eps = 1e-9;
        let left = env.lookup(direction_from_uv(1.0 - eps, 0.4));
        let right = env.lookup(direction_from_uv(eps, 0.4));
        for k in 0..3 {
            assert!((left[k] - right[k]).abs() < 1e-6, "{left:?} vs {right:?}");
        }
        // Latitude clamps at the poles instead of wrapping.
        assert_eq!(map.sample_uv(0.5 / w as f64, 0.0), px(0, 0));
        assert_eq!(map.sample_uv(0.5 / w as f64, 1.0), px(0, h - 1));
    }

    #[test]
    fn bad_values_are_zeroed_and_sizes_checked() {
        let map =
            LatLongMap::new(2, 1, vec![[f32::NAN, -1.0, 2.0], [f32::INFINITY, 0.5, 0.0]]).unwrap();
        assert_eq!(map.data(), &[[0.0, 0.0, 2.0], [0.0, 0.5, 0.0]]);
        assert!(matches!(
            LatLongMap::new(2, 2, vec![[0.0; 3]; 3]),
            Err(EnvironmentError::Size { len: 3, .. })
        ));
        assert!(LatLongMap::new(0, 0, vec![]).is_err());
        let env = Environment::LatLong(map);
        assert!(env.lookup(DVec3::ZERO)[0].is_nan());
        assert!(env.lookup(DVec3::new(f64::NAN, 0.0, 1.0))[0].is_nan());
    }

    #[test]
    fn missing_file_error_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no-such-map.exr");
        let err = Environment::from_exr(&path).unwrap_err();
        assert!(matches!(err, EnvironmentError::Io { .. }), "{err:?}");
        assert!(err.to_string().contains("no-such-map.exr"), "{err}");
    }

    #[test]
    fn non_exr_file_is_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sky.exr");
        std::fs::write(&path, b"P3\n1 1\n255\n0 0 0\n").unwrap();
        let err = Environment::from_exr(&path).unwrap_err();
        assert!(matches!(err, EnvironmentError::NotExr { .. }), "{err:?}");
        assert!(err.to_string().contains("sky.exr"), "{err}");
        // Empty file too.
        std::fs::write(&path, b"").unwrap();
        assert!(matches!(
            Environment::from_exr(&path),
            Err(EnvironmentError::NotExr { .. })
        ));
    }

    #[test]
    fn exr_without_rgb_is_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("luma.exr");
        let channels = SpecificChannels::build()
            .with_channel("Y")
            .with_pixel_fn(|_| (0.5f32,));
        exr::prelude::Image::from_channels((4, 2), channels)
            .write()
            .non_parallel()
            .to_file(&path)
            .unwrap();
        let err = Environment::from_exr(&path).unwrap_err();
        match &err {
            EnvironmentError::NoRgb { found, .. } => assert_eq!(found, "Y"),
            other => panic!("expected NoRgb, got {other:?}"),
        }
        assert!(err.to_string().contains("luma.exr"), "{err}");
    }

    #[test]
    fn truncated_exr_is_a_decode_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cut.exr");
        write_exr(&path, 16, 8, &ramp(16, 8));
        let bytes = std::fs::read(&path).unwrap();
        for cut in [8, bytes.len() / 2, bytes.len() - 4] {
            let err = LatLongMap::from_exr_bytes(&bytes[..cut], &path).unwrap_err();
            assert!(
                matches!(err, EnvironmentError::Decode { .. }),
                "{cut}: {err:?}"
            );
            assert!(err.to_string().contains("cut.exr"));
        }
    }

    /// Found by `tests/fuzz.rs` (family `exr`): a header whose data window
    /// announces far more texels than the file holds is refused before
    /// decoding; an 800-byte file asking for 10289168 x 8 texels took
    /// seconds and a gigabyte.
    #[test]
    fn header_larger_than_the_file_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wide.exr");
        write_exr(&path, 16, 8, &ramp(16, 8));
        let mut bytes = std::fs::read(&path).unwrap();
        let key = b"dataWindow\0box2i\0";
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        // x max of the box (x min, y min, x max, y max).
        bytes[at + 8..at + 12].copy_from_slice(&10_289_167i32.to_le_bytes());
        let start = std::time::Instant::now();
        let err = LatLongMap::from_exr_bytes(&bytes, &path).unwrap_err();
        assert!(start.elapsed().as_secs_f64() < 0.5, "{:?}", start.elapsed());
        assert!(
            matches!(
                err,
                EnvironmentError::Corrupt {
                    width: 10_289_168,
                    height: 8,
                    ..
                }
            ),
            "{err:?}"
        );
        assert!(err.to_string().contains("wide.exr"), "{err}");
        // A map that compresses about as well as zip can (one colour) loads.
        let (w, h) = (1024, 512);
        let layer = exr::prelude::Layer::new(
            (w, h),
            exr::prelude::LayerAttributes::default(),
            exr::prelude::Encoding::SMALL_LOSSLESS,
            SpecificChannels::rgb(|_| (0.25f32, 0.5f32, 1.0f32)),
        );
        let mut bytes = Vec::new();
        exr::prelude::Image::from_layer(layer)
            .write()
            .non_parallel()
            .to_buffered(std::io::Cursor::new(&mut bytes))
            .unwrap();
        let ratio = (w * h * 12) as f64 / bytes.len() as f64;
        assert!(ratio > 100.0, "{ratio}");
        let map = LatLongMap::from_exr_bytes(&bytes, &path).unwrap();
        assert_eq!((map.width(), map.height()), (w, h));
    }

    #[test]
    fn procedural_sky_is_plausible() {
        let sky = Sky::default();
        let env = sky.build();
        let Environment::LatLong(map) = &env else {
            panic!("expected a lat-long map")
        };
        assert_eq!((map.width(), map.height()), (512, 256));
        assert!(map
            .data()
            .iter()
            .flatten()
            .all(|c| c.is_finite() && *c >= 0.0));
        let lum = |c: [f64; 3]| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
        let sun = lum(env.lookup(sky.sun_direction));
        let zenith = lum(env.lookup(DVec3::Y));
        let horizon = lum(env.lookup(DVec3::new(-1.0, 0.05, 0.0)));
        let ground = lum(env.lookup(DVec3::new(0.0, -0.5, 1.0)));
        assert!(sun > 100.0 * zenith, "sun {sun} zenith {zenith}");
        assert!(horizon > zenith && zenith > ground && ground > 0.0);
        // The sky is blue overhead.
        let z = env.lookup(DVec3::Y);
        assert!(z[2] > z[0]);
        assert_eq!(Environment::sky(), env);
    }
}
