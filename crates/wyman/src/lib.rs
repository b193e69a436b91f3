//! # eikon-wyman
//!
//! The image-space baseline: Wyman's two-interface refraction and caustic
//! maps (Wyman, "Interactive Refractions and Caustics Using Image-Space
//! Techniques", ShaderX5, 2006), as wgpu render pipelines (rasterization,
//! no compute shaders). It gives an instant preview of a mesh object and
//! the speed and error baseline the eikonal and exact renderers are
//! measured against.
//!
//! ## A frame
//!
//! Per light (only where the scene has a receiver), in the light's view at
//! `photons` x `photons` texels (orthographic for a directional light, a
//! pinhole at a point light):
//!
//! 1. back faces: normal N2 and view distance (`rgba32float`, depth
//!    `GREATER`: the farthest back surface, the paper's choice for
//!    non-convex objects);
//! 2. front faces: p1 with `d_N`, N1 with its view distance (two
//!    `rgba32float` targets; the second is the shadow map);
//! 3. refraction, a full-screen triangle: per front texel the exit ray
//!    (p2 and status, T2 and the Fresnel transmittance; two `rgba32float`);
//! 4. splats: one instanced quad of `splat` x `splat` texels per photon
//!    into the caustic map (`caustic_map` x `caustic_map` texels of three
//!    64-bit fixed-point sums), where its exit ray meets the receiver plane.
//!
//! Then in the eye's view, at the image size: passes 1-3 again. One
//! readback: the eye's G-buffer and exit rays (four `rgba32float` images),
//! each light's shadow map and caustic map. The CPU shades every pixel
//! (rayon, the same bits whatever the thread count) through
//! [`eikon_view::Surroundings::radiance`], the renderer's one definition of
//! the background (receiver, checkerboard, environment): Fresnel
//! reflection at the front surface, and the exit ray with both
//! interfaces' Fresnel transmission and Beer-Lambert attenuation over the
//! estimated inside path. The receiver is lit by each light's direct
//! irradiance times the shadow map's visibility plus the caustic map
//! ([`eikon_view::Surroundings::with_light_factor`]).
//!
//! ## What it approximates
//!
//! * The distance to the back surface along the refracted ray is the
//!   paper's interpolation between the view-ray thickness `d_V` and the
//!   thickness along the inward normal `d_N` [Wyman06 eq 6.3.1]; `d_N` is
//!   ray cast once per vertex ([`Refractor::corners`]) and interpolated.
//! * The back normal N2 is read where the estimated exit point projects in
//!   the back-face image (nearest texel); where no back face is there, the
//!   normal perpendicular to the view [Wyman06 eq 6.3.2].
//! * Exactly two refractions: no internal reflections beyond what the
//!   [`Tir`] choice does where the back refraction is total, the front
//!   surface's reflection sees the background without meeting the object
//!   again, and the exit ray does not meet the object again.
//! * Caustic maps: photons are the light-view texels, each followed through
//!   two refractions to the receiver plane only (nothing else receives
//!   caustics), splatted with Gaussian weights that sum to the paper's
//!   R; shadows come from the light view's front-surface depth, filtered
//!   over the four nearest texels.
//! * Not handled: scattering and emission inside (the medium only
//!   attenuates), dispersion, graded indices, more than one object, spot
//!   lights, a camera or light inside the object (all refused or said).
//!
//! See docs/ARCHITECTURE.md (Wyman's image-space baseline) and
//! docs/PERFORMANCE.md for measured error and speed.

pub mod caustic;
pub mod gpu;
pub mod refractor;
pub mod render;
pub mod view;

pub use caustic::CausticMap;
pub use gpu::{Exit, ExitRays, Raster};
pub use refractor::{Refractor, Shading};
pub use render::{render, Renderer, Stats};
pub use view::View;

/// What total internal reflection at the back surface becomes: the
/// paper's three ad hoc fills ("Fixing Problem Cases").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[repr(u32)]
pub enum Tir {
    /// Degenerate to one refraction: T2 = T1.
    Single,
    /// Clamp the incidence to the critical angle: leave along the surface.
    Clamp,
    /// Reflect at the back surface and ignore further interactions (the
    /// default: its power is the whole transmitted part, as physics says).
    #[default]
    Reflect,
}

/// Sizes and choices of a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Photons per side of the light's view (photon buffer and shadow
    /// map): `photons^2` in all.
    pub photons: u32,
    /// Texels per side of the caustic map.
    pub caustic_map: u32,
    /// Texels per side of a photon's splat (odd).
    pub splat: u32,
    /// The caustic map covers this many times the photon buffer's view
    /// (light refracted out to the side lands beyond the object's outline).
    pub caustic_extent: f64,
    /// Total internal reflection at the back surface.
    pub tir: Tir,
}

impl Default for Settings {
    /// The paper's usual sizes: 512^2 photons into a caustic map of half
    /// their resolution (over the same view) with 7 x 7 Gaussian splats.
    fn default() -> Self {
        Settings {
            photons: 512,
            caustic_map: 512,
            splat: 7,
            caustic_extent: 2.0,
            tir: Tir::Reflect,
        }
    }
}

impl Settings {
    /// The paper's R: caustic-map texels per photon over the same area of
    /// the light's image plane.
    pub fn texels_per_photon(&self) -> f64 {
        let c = f64::from(self.caustic_map) / self.caustic_extent;
        let p = f64::from(self.photons);
        (c * c) / (p * p)
    }

    /// Gaussian sigma of a splat, caustic texels: a sixth of its side, so
    /// the splat is cut three sigma out.
    pub fn splat_sigma(&self) -> f64 {
        f64::from(self.splat) / 6.0
    }

    /// Checks the sizes against each other and the device's limit.
    pub fn check(&self, max_texture: u32) -> Result<(), WymanError> {
        let bad = |what: &str, msg: String| Err(WymanError::Settings(format!("{what}: {msg}")));
        if !(1..=max_texture).contains(&self.photons) {
            return bad(
                "photons",
                format!("must lie in 1..={max_texture}, got {}", self.photons),
            );
        }
        if !(1..=max_texture).contains(&self.caustic_map) {
            return bad(
                "caustic map",
                format!("must lie in 1..={max_texture}, got {}", self.caustic_map),
            );
        }
        if self.splat.is_multiple_of(2) || !(1..=31).contains(&self.splat) {
            return bad(
                "splat",
                format!("must be odd and at most 31, got {}", self.splat),
            );
        }
        if !(self.caustic_extent >= 1.0 && self.caustic_extent <= 16.0) {
            return bad(
                "caustic extent",
                format!("must lie in [1, 16], got {}", self.caustic_extent),
            );
        }
        Ok(())
    }
}

/// What can go wrong.
#[derive(Debug, thiserror::Error)]
pub enum WymanError {
    /// The scene asks for something the method does not do.
    #[error(transparent)]
    Scene(#[from] eikon_grid::Error),
    /// The mesh is not a closed, outward surface.
    #[error(transparent)]
    Mesh(#[from] eikon_mesh::MeshError),
    /// The device failed or refused.
    #[error(transparent)]
    Gpu(#[from] eikon_gpu::GpuError),
    /// The background could not be loaded.
    #[error(transparent)]
    Environment(#[from] eikon_optics::EnvironmentError),
    /// Settings out of range.
    #[error("{0}")]
    Settings(String),
}
