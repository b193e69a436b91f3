//! HDR images, OpenEXR output and tone mapping to 8-bit sRGB PNG.
//!
//! The renderer works in linear, scene-referred RGB radiance
//! ([Ihrke07 sec 5.3]: "all lighting computations are performed in high
//! dynamic range"). [`encode_exr`] stores that verbatim; [`encode_png`] maps it
//! to a display image with the operator described at [`ToneMap`]. The paper
//! uses the temporally adaptive operator of Krawczyk et al. 2005 for
//! interactive display; for still images its global part reduces to
//! Reinhard et al.'s 2002 photographic operator, which is what is implemented
//! here.
//!
//! Both encoders return bytes; writing them to disk (atomically) is the
//! caller's business.

use std::io::Cursor;

/// Why an image could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// A dimension is zero or `data.len() != width * height`.
    #[error("image of {width}x{height} pixels needs {} values, got {len}", u64::from(*width) * u64::from(*height))]
    Size {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// Number of pixels supplied.
        len: usize,
    },
    /// The tone-mapping parameters are unusable (non-finite exposure, or a
    /// key that is not a positive finite number).
    #[error("invalid tone mapping: {0}")]
    ToneMap(String),
    /// The OpenEXR encoder failed.
    #[error("cannot encode OpenEXR image")]
    Exr(#[source] exr::error::Error),
    /// The PNG encoder failed.
    #[error("cannot encode PNG image")]
    Png(#[source] png::EncodingError),
}

/// A linear HDR RGB image, row-major with the **top row first** (pixel
/// `(0, 0)` is the top-left corner, as for [`crate::camera::Camera`]).
///
/// Fields are public so a renderer can fill `data` directly; the encoders
/// check `data.len() == width * height` and report a mismatch as an error.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height` pixels, row `y` at `data[y * width .. (y + 1) * width]`.
    pub data: Vec<[f32; 3]>,
}

impl Image {
    /// A black `width × height` image.
    pub fn new(width: u32, height: u32) -> Image {
        Image {
            width,
            height,
            data: vec![[0.0; 3]; width as usize * height as usize],
        }
    }

    /// An image from row-major pixels, top row first.
    ///
    /// # Errors
    ///
    /// [`ImageError::Size`] if a dimension is zero or the length is wrong.
    pub fn from_data(width: u32, height: u32, data: Vec<[f32; 3]>) -> Result<Image, ImageError> {
        let image = Image {
            width,
            height,
            data,
        };
        image.check()?;
        Ok(image)
    }

    /// Checks that the image is non-empty and `data` has `width * height`
    /// pixels.
    ///
    /// # Errors
    ///
    /// [`ImageError::Size`] otherwise.
    pub fn check(&self) -> Result<(), ImageError> {
        let n = u64::from(self.width) * u64::from(self.height);
        if n == 0 || n != self.data.len() as u64 {
            return Err(ImageError::Size {
                width: self.width,
                height: self.height,
                len: self.data.len(),
            });
        }
        Ok(())
    }

    /// Pixel `(x, y)`, or `None` outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> Option<[f32; 3]> {
        self.index(x, y).and_then(|i| self.data.get(i).copied())
    }

    /// Mutable pixel `(x, y)`, or `None` outside the image.
    pub fn pixel_mut(&mut self, x: u32, y: u32) -> Option<&mut [f32; 3]> {
        self.index(x, y).and_then(|i| self.data.get_mut(i))
    }

    fn index(&self, x: u32, y: u32) -> Option<usize> {
        (x < self.width && y < self.height).then(|| y as usize * self.width as usize + x as usize)
    }
}

/// Luminance of linear RGB with Rec. 709 / sRGB primaries (the primaries the
/// PNG output is tagged with): `0.2126 R + 0.7152 G + 0.0722 B`.
pub fn luminance(rgb: [f32; 3]) -> f64 {
    0.2126 * f64::from(rgb[0]) + 0.7152 * f64::from(rgb[1]) + 0.0722 * f64::from(rgb[2])
}

/// Offset δ in the log-average luminance; keeps `ln` finite on black pixels.
pub const LOG_AVERAGE_DELTA: f64 = 1e-6;

/// Log-average ("geometric mean") luminance of the image
/// ([Reinhard02 eq 1]), `exp(mean(ln(δ + L))) − δ` with δ =
/// [`LOG_AVERAGE_DELTA`].
///
/// Pixels with a non-finite channel are **ignored**: one NaN or inf (a
/// diverged ray) would otherwise turn the mean into NaN/inf and the whole
/// image black. Negative luminances are clamped to 0 (they cannot occur
/// physically and `ln` of them is undefined). Subtracting δ again makes a
/// constant image's log-average exactly its luminance, so auto exposure is
/// independent of the absolute level even for very dark images.
///
/// `None` if no pixel is finite.
pub fn log_average_luminance(image: &Image) -> Option<f64> {
    let (mut sum, mut n) = (0.0f64, 0u64);
    for &p in &image.data {
        if p.iter().all(|c| c.is_finite()) {
            sum += (LOG_AVERAGE_DELTA + luminance(p).max(0.0)).ln();
            n += 1;
        }
    }
    (n > 0).then(|| ((sum / n as f64).exp() - LOG_AVERAGE_DELTA).max(0.0))
}

/// How the HDR radiance is scaled before the tone curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Exposure {
    /// Multiply radiance by `2^stops` (0 = as rendered).
    Fixed(f64),
    /// Scale so that the log-average luminance maps to [`ToneMap::key`].
    Auto,
}

/// Tone-mapping operator from linear HDR RGB to 8-bit sRGB.
///
/// For each pixel with linear RGB `c` and luminance `L` ([`luminance`]):
///
/// 1. **Exposure**: `s = 2^stops` for [`Exposure::Fixed`]; for
///    [`Exposure::Auto`], `s = key / L̄` with `L̄` the
///    [`log_average_luminance`] (Reinhard et al. 2002: a scene's "key").
///    If `L̄` is 0 or undefined (an all-black or all-NaN image), `s = 1`.
/// 2. **Reinhard global operator on luminance**: `Ls = s L`,
///    `Ld = Ls / (1 + Ls)`, and the colour is scaled by `Ld / L`, i.e.
///    `c_out = s c / (1 + Ls)`. Applied to luminance rather than per
///    channel because that keeps the ratios between R, G and B, so the hue
///    and saturation of coloured attenuation, dispersion and caustics survive
///    compression; per-channel compression would push bright saturated
///    colours towards white and shift hues. The price is that a very bright,
///    very saturated colour can exceed 1 in one channel; it is clipped.
/// 3. **sRGB OETF** ([`srgb_oetf`]) and rounding to 8 bits ([`quantize`]).
///
/// Pixels with a non-finite channel are written black (they are also
/// excluded from auto exposure); negative channels are clamped to 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToneMap {
    /// Exposure mode.
    pub exposure: Exposure,
    /// Target value for the log-average luminance under
    /// [`Exposure::Auto`]; Reinhard's "middle grey" 0.18 by default.
    pub key: f64,
}

impl Default for ToneMap {
    /// Auto exposure with key 0.18.
    fn default() -> Self {
        ToneMap {
            exposure: Exposure::Auto,
            key: 0.18,
        }
    }
}

impl ToneMap {
    /// Checks the parameters: the exposure must be finite and the key a
    /// positive finite number.
    ///
    /// # Errors
    ///
    /// [`ImageError::ToneMap`] otherwise.
    pub fn check(&self) -> Result<(), ImageError> {
        if let Exposure::Fixed(stops) = self.exposure {
            if !stops.is_finite() {
                return Err(ImageError::ToneMap(format!(
                    "exposure must be finite, got {stops} stops"
                )));
            }
        }
        if !(self.key > 0.0 && self.key.is_finite()) {
            return Err(ImageError::ToneMap(format!(
                "key must be positive and finite, got {}",
                self.key
            )));
        }
        Ok(())
    }

    /// The radiance scale `s` of step 1 for this image. Invalid parameters
    /// (see [`check`](Self::check)) give a non-finite or zero scale, which
    /// turns every pixel black rather than panicking.
    pub fn scale(&self, image: &Image) -> f64 {
        match self.exposure {
            Exposure::Fixed(stops) => stops.exp2(),
            Exposure::Auto => match log_average_luminance(image) {
                Some(avg) if avg > 0.0 => self.key / avg,
                _ => 1.0,
            },
        }
    }

    /// Step 2 for one pixel: the linear display value `s c / (1 + s L)`,
    /// clipped to `[0, 1]`, for exposure scale `s`. Non-finite inputs give
    /// black.
    pub fn map_linear(&self, rgb: [f32; 3], scale: f64) -> [f64; 3] {
        if !(rgb.iter().all(|c| c.is_finite()) && scale.is_finite()) {
            return [0.0; 3];
        }
        let c = rgb.map(|c| c.max(0.0));
        let ls = scale * luminance(c);
        if !(ls > 0.0 && ls.is_finite()) {
            return [0.0; 3];
        }
        let factor = scale / (1.0 + ls);
        c.map(|c| (f64::from(c) * factor).min(1.0))
    }

    /// Steps 2-3 for one pixel, given the exposure scale `s`.
    pub fn map_pixel(&self, rgb: [f32; 3], scale: f64) -> [u8; 3] {
        self.map_linear(rgb, scale).map(|c| quantize(srgb_oetf(c)))
    }
}

/// The sRGB opto-electronic transfer function (IEC 61966-2-1): linear
/// `[0, 1]` to encoded `[0, 1]`; inputs are clamped to `[0, 1]`, NaN gives 0.
pub fn srgb_oetf(linear: f64) -> f64 {
    // clamp would keep NaN; map it to 0 explicitly.
    if linear.is_nan() {
        return 0.0;
    }
    let x = linear.clamp(0.0, 1.0);
    if x <= 0.003_130_8 {
        12.92 * x
    } else if x == 1.0 {
        // 1.055 − 0.055 rounds to 1 − 2^-53; white must stay exactly white.
        1.0
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// An encoded value in `[0, 1]` to 8 bits, rounding to nearest (clamped).
pub fn quantize(encoded: f64) -> u8 {
    (encoded * 255.0 + 0.5).floor().clamp(0.0, 255.0) as u8
}

/// The tone-mapped 8-bit sRGB pixels of `image` (row-major, top row first),
/// one per element of `image.data`; see [`ToneMap`] for the operator.
pub fn tonemapped(image: &Image, tone: &ToneMap) -> Vec<[u8; 3]> {
    let scale = tone.scale(image);
    image
        .data
        .iter()
        .map(|&p| tone.map_pixel(p, scale))
        .collect()
}

/// Encodes the image as an 8-bit RGB PNG tagged as sRGB, after tone mapping
/// with `tone`.
///
/// # Errors
///
/// [`ImageError::Size`] for inconsistent dimensions, [`ImageError::ToneMap`]
/// for invalid parameters, [`ImageError::Png`] if encoding fails.
pub fn encode_png(image: &Image, tone: &ToneMap) -> Result<Vec<u8>, ImageError> {
    image.check()?;
    tone.check()?;
    let pixels: Vec<u8> = tonemapped(image, tone).into_iter().flatten().collect();
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, image.width, image.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    // The values went through the sRGB OETF; say so, so viewers do not
    // apply another gamma guess.
    encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    let mut writer = encoder.write_header().map_err(ImageError::Png)?;
    writer.write_image_data(&pixels).map_err(ImageError::Png)?;
    writer.finish().map_err(ImageError::Png)?;
    Ok(out)
}

/// Encodes the image as a scan-line OpenEXR file with 32-bit float R, G, B
/// channels and lossless ZIP compression: the radiance is stored exactly
/// (bit for bit, including NaN and inf).
///
/// # Errors
///
/// [`ImageError::Size`] for inconsistent dimensions, [`ImageError::Exr`] if
/// encoding fails.
pub fn encode_exr(image: &Image) -> Result<Vec<u8>, ImageError> {
    use exr::prelude::{Encoding, Layer, LayerAttributes, SpecificChannels, Vec2, WritableImage};
    image.check()?;
    let width = image.width as usize;
    let height = image.height as usize;
    let data = &image.data;
    let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
        let p = data[pos.y() * width + pos.x()];
        (p[0], p[1], p[2])
    });
    let layer = Layer::new(
        (width, height),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        channels,
    );
    let mut out = Cursor::new(Vec::new());
    exr::prelude::Image::from_layer(layer)
        .write()
        // The crate is built without exr's rayon feature (see Cargo.toml).
        .non_parallel()
        .to_buffered(&mut out)
        .map_err(ImageError::Exr)?;
    Ok(out.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use exr::prelude::{ReadChannels, ReadLayers};

    fn read_exr(bytes: &[u8]) -> (usize, usize, Vec<[f32; 3]>) {
        let image = exr::prelude::read()
            .no_deep_data()
            .largest_resolution_level()
            .rgb_channels(
                |size, _| (size.width(), vec![[0.0f32; 3]; size.area()]),
                |(w, px): &mut (usize, Vec<[f32; 3]>),
                 pos: exr::prelude::Vec2<usize>,
                 (r, g, b): (f32, f32, f32)| {
                    px[pos.y() * *w + pos.x()] = [r, g, b];
                },
            )
            .first_valid_layer()
            .all_attributes()
            .non_parallel()
            .from_buffered(Cursor::new(bytes))
            .unwrap();
        let size = image.layer_data.size;
        (
            size.width(),
            size.height(),
            image.layer_data.channel_data.pixels.1,
        )
    }

    fn constant(w: u32, h: u32, c: [f32; 3]) -> Image {
        Image::from_data(w, h, vec![c; (w * h) as usize]).unwrap()
    }

    #[test]
    fn exr_round_trip_is_bit_exact() {
        let (w, h) = (7u32, 5u32);
        let mut data: Vec<[f32; 3]> = (0..w * h)
            .map(|k| {
                let x = k as f32;
                [x * 0.1, 1.0 / (x + 1.0), (x * 1.7).sin() * 1e3]
            })
            .collect();
        // Values a lossy or clamping path would change.
        data[3] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
        data[4] = [1e-40, -0.0, f32::MAX];
        data[5] = [65504.0 * 4.0, 1.0 + f32::EPSILON, -3.5];
        let image = Image::from_data(w, h, data.clone()).unwrap();
        let bytes = encode_exr(&image).unwrap();
        let (rw, rh, back) = read_exr(&bytes);
        assert_eq!((rw, rh), (7, 5));
        let bits =
            |v: &[[f32; 3]]| -> Vec<u32> { v.iter().flatten().map(|c| c.to_bits()).collect() };
        assert_eq!(bits(&back), bits(&data));
        // Row order: the first stored row is the top row.
        assert_eq!(back[1], data[1]);
    }

    #[test]
    fn inconsistent_images_are_errors_not_panics() {
        let bad = Image {
            width: 3,
            height: 2,
            data: vec![[0.0; 3]; 5],
        };
        assert!(matches!(
            encode_exr(&bad),
            Err(ImageError::Size { len: 5, .. })
        ));
        assert!(matches!(
            encode_png(&bad, &ToneMap::default()),
            Err(ImageError::Size { .. })
        ));
        assert!(Image::from_data(0, 3, vec![]).is_err());
        assert_eq!(tonemapped(&bad, &ToneMap::default()).len(), 5);
        let mut img = Image::new(3, 2);
        assert_eq!(img.pixel(3, 0), None);
        *img.pixel_mut(2, 1).unwrap() = [1.0, 2.0, 3.0];
        assert_eq!(img.data[5], [1.0, 2.0, 3.0]);
        let bad_key = ToneMap {
            exposure: Exposure::Auto,
            key: 0.0,
        };
        assert!(matches!(
            encode_png(&img, &bad_key),
            Err(ImageError::ToneMap(_))
        ));
        let bad_stops = ToneMap {
            exposure: Exposure::Fixed(f64::NAN),
            ..ToneMap::default()
        };
        assert!(matches!(
            encode_png(&img, &bad_stops),
            Err(ImageError::ToneMap(_))
        ));
        assert!(tonemapped(&img, &bad_stops).iter().all(|p| *p == [0; 3]));
    }

    #[test]
    fn log_average_of_constant_image_is_the_constant() {
        for level in [0.0f32, 1e-7, 1e-3, 0.18, 1.0, 37.5, 1e5] {
            let c = [level, level, level];
            let avg = log_average_luminance(&constant(5, 4, c)).unwrap();
            let want = luminance(c);
            assert!(
                (avg - want).abs() <= 1e-12 * want.max(1e-6),
                "{level}: {avg}"
            );
        }
        // A coloured constant: its luminance.
        let c = [0.2, 0.5, 1.0];
        let avg = log_average_luminance(&constant(3, 3, c)).unwrap();
        assert!((avg - luminance(c)).abs() < 1e-12);
        // It is a geometric, not arithmetic, mean: half at 1, half at 4 -> 2
        // (up to the small δ).
        let mut img = constant(2, 1, [1.0; 3]);
        img.data[1] = [4.0; 3];
        assert!((log_average_luminance(&img).unwrap() - 2.0).abs() < 1e-5);
    }

    #[test]
    fn non_finite_pixels_do_not_poison_auto_exposure() {
        let c = [0.7f32, 0.7, 0.7];
        let clean = constant(8, 8, c);
        let mut dirty = clean.clone();
        dirty.data[0] = [f32::NAN, 0.0, 0.0];
        dirty.data[9] = [f32::INFINITY; 3];
        dirty.data[20] = [1.0, f32::NEG_INFINITY, 1.0];
        let avg = log_average_luminance(&dirty).unwrap();
        assert!((avg - luminance(c)).abs() < 1e-12);
        let tone = ToneMap::default();
        assert_eq!(tone.scale(&dirty), tone.scale(&clean));
        let out = tonemapped(&dirty, &tone);
        let good = tonemapped(&clean, &tone)[1];
        assert_eq!(out[0], [0; 3]);
        assert_eq!(out[9], [0; 3]);
        assert_eq!(out[1], good);
        assert!(good[0] > 0);
        // All non-finite: no average, unit scale.
        let nan = constant(2, 2, [f32::NAN; 3]);
        assert_eq!(log_average_luminance(&nan), None);
        assert_eq!(tone.scale(&nan), 1.0);
    }

    #[test]
    fn auto_exposure_is_scale_invariant() {
        let tone = ToneMap::default();
        // key 0.18 -> Reinhard 0.18/1.18 -> sRGB -> 8 bit.
        let want = quantize(srgb_oetf(0.18 / 1.18));
        for level in [1e-6f32, 1e-3, 0.5, 1.0, 250.0, 3e6] {
            let out = tonemapped(&constant(4, 3, [level; 3]), &tone);
            assert!(out.iter().all(|&p| p == [want; 3]), "{level}: {:?}", out[0]);
            // A coloured constant keeps its colour at every level.
            let col = [0.3 * level, 0.6 * level, 0.1 * level];
            let a = tonemapped(&constant(2, 2, col), &tone)[0];
            let b = tonemapped(&constant(2, 2, [0.3, 0.6, 0.1]), &tone)[0];
            assert_eq!(a, b, "{level}");
        }
        // Black stays black (no division by zero).
        assert!(tonemapped(&constant(2, 2, [0.0; 3]), &tone)
            .iter()
            .all(|&p| p == [0; 3]));
    }

    #[test]
    fn fixed_exposure_and_reinhard_curve() {
        let img = constant(1, 1, [1.0; 3]);
        // L = 1 at 0 stops -> 1/2; at +1 stop L = 2 -> 2/3.
        let at = |stops: f64| {
            let t = ToneMap {
                exposure: Exposure::Fixed(stops),
                ..ToneMap::default()
            };
            tonemapped(&img, &t)[0][0]
        };
        assert_eq!(at(0.0), quantize(srgb_oetf(0.5)));
        assert_eq!(at(1.0), quantize(srgb_oetf(2.0 / 3.0)));
        assert_eq!(at(-1.0), quantize(srgb_oetf(1.0 / 3.0)));
        // Hue is preserved: channel ratios survive where nothing clips.
        let t = ToneMap::default();
        let c = [0.8f32, 0.4, 0.2];
        let l = luminance(c);
        for s in [0.5, 1.0, 3.0] {
            let out = t.map_linear(c, s);
            for k in 0..3 {
                let want = s * f64::from(c[k]) / (1.0 + s * l);
                assert!((out[k] - want).abs() < 1e-15, "{s} {k}");
            }
            assert!((out[0] / out[2] - 4.0).abs() < 1e-12);
        }
        // A very bright saturated blue clips in its own channel only.
        let out = t.map_linear([0.0, 0.0, 50.0], 1.0);
        assert_eq!(out, [0.0, 0.0, 1.0]);
        // Negative channels count as 0.
        assert_eq!(t.map_linear([-1.0, 0.0, 0.0], 1.0), [0.0; 3]);
    }

    #[test]
    fn srgb_endpoints_and_curve() {
        assert_eq!(quantize(srgb_oetf(0.0)), 0);
        assert_eq!(quantize(srgb_oetf(1.0)), 255);
        assert_eq!(srgb_oetf(1.0), 1.0);
        assert_eq!(srgb_oetf(0.0), 0.0);
        // Clamping and NaN.
        assert_eq!(srgb_oetf(7.0), 1.0);
        assert_eq!(srgb_oetf(-1.0), 0.0);
        assert_eq!(srgb_oetf(f64::NAN), 0.0);
        // Linear 0.18 encodes to about 0.4614 (the well-known 118/255).
        assert!((srgb_oetf(0.18) - 0.461_356).abs() < 1e-5);
        assert_eq!(quantize(srgb_oetf(0.18)), 118);
        // The two branches meet continuously at the breakpoint.
        let b = 0.003_130_8;
        assert!((12.92 * b - (1.055 * f64::powf(b, 1.0 / 2.4) - 0.055)).abs() < 1e-6);
        // Monotone.
        let mut prev = -1.0;
        for k in 0..=1000 {
            let v = srgb_oetf(k as f64 / 1000.0);
            assert!(v > prev);
            prev = v;
        }
    }

    #[test]
    fn png_decodes_to_the_tonemapped_pixels() {
        let (w, h) = (5u32, 3u32);
        let data: Vec<[f32; 3]> = (0..w * h)
            .map(|k| [k as f32 * 0.3, 1.0, (k % 4) as f32 * 2.0])
            .collect();
        let img = Image::from_data(w, h, data).unwrap();
        let tone = ToneMap::default();
        let bytes = encode_png(&img, &tone).unwrap();
        let decoder = png::Decoder::new(Cursor::new(bytes));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (w, h));
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(info.bit_depth, png::BitDepth::Eight);
        assert!(reader.info().srgb.is_some());
        let want: Vec<u8> = tonemapped(&img, &tone).into_iter().flatten().collect();
        assert_eq!(&buf[..info.buffer_size()], &want[..]);
    }
}
