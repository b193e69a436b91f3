//! Scene objects: a shape, its optical material and a priority.

use crate::shape::Shape;
use crate::vdb::FloatVolume;
use glam::DVec3;
use std::sync::Arc;

/// How the refractive index varies inside an object.
#[derive(Clone, Debug)]
pub enum IndexProfile {
    /// Constant index per colour channel (R, G, B; equal without dispersion).
    Constant([f64; 3]),
    /// Luneburg lens `n = outer * sqrt(2 - (r/R)^2)` about `center`.
    Luneburg {
        /// Lens centre.
        center: DVec3,
        /// Lens radius R.
        radius: f64,
        /// Index of the surrounding medium the lens is matched to.
        outer: f64,
    },
    /// Linear index `n = n0 + gradient . (x - origin)`.
    Linear {
        /// Index at `origin`.
        n0: f64,
        /// Gradient of n, per world unit.
        gradient: DVec3,
        /// Point where n = n0.
        origin: DVec3,
    },
}

impl IndexProfile {
    /// Exact index and gradient at `p` for colour `channel` (0..3).
    #[inline]
    pub fn sample(&self, p: DVec3, channel: usize) -> (f64, DVec3) {
        match self {
            IndexProfile::Constant(n) => (n[channel], DVec3::ZERO),
            IndexProfile::Luneburg {
                center,
                radius,
                outer,
            } => {
                let d = p - *center;
                let s = (2.0 - d.length_squared() / (radius * radius)).max(1.0);
                let n = outer * s.sqrt();
                // dn/dx = outer * (-x / R^2) / sqrt(s) = -outer^2 x / (R^2 n)
                (n, -d * (outer * outer) / (radius * radius * n))
            }
            IndexProfile::Linear {
                n0,
                gradient,
                origin,
            } => (n0 + gradient.dot(p - *origin), *gradient),
        }
    }

    /// Exact index at `p` for `channel`.
    #[inline]
    pub fn value(&self, p: DVec3, channel: usize) -> f64 {
        self.sample(p, channel).0
    }

    /// Whether every colour channel sees the same index everywhere (no
    /// dispersion), so that rays of every colour take one path.
    pub fn achromatic(&self) -> bool {
        match self {
            IndexProfile::Constant([r, g, b]) => r == g && g == b,
            IndexProfile::Luneburg { .. } | IndexProfile::Linear { .. } => true,
        }
    }
}

/// Optical properties of a medium (an object's interior or the ambient).
#[derive(Clone, Debug)]
pub struct Material {
    /// Refractive index.
    pub index: IndexProfile,
    /// RGB extinction coefficient sigma_t = sigma_a + sigma_s, per world unit.
    pub extinction: DVec3,
    /// RGB single-scattering albedo sigma_s / sigma_t, in [0, 1].
    pub albedo: DVec3,
    /// Henyey-Greenstein asymmetry g, in (-1, 1).
    pub g: f64,
    /// RGB emitted radiance per world unit of path (W / (m^2 sr) per unit length).
    pub emission: DVec3,
    /// The index read from a VDB float grid instead of `index` (which then
    /// holds the largest index of the grid, for listings).
    pub index_grid: Option<GridIndex>,
    /// The extinction read from a VDB float grid instead of `extinction`
    /// (which then holds the largest extinction of the grid).
    pub extinction_grid: Option<GridExtinction>,
}

/// Refractive index from a VDB float grid (trilinear between voxel centres).
#[derive(Clone, Debug)]
pub struct GridIndex {
    /// The grid.
    pub volume: Arc<FloatVolume>,
    /// `None`: the grid holds n itself; `Some(k)`: n = 1 + k * value (a
    /// density grid).
    pub scale: Option<f64>,
}

impl GridIndex {
    /// The index at `p`.
    #[inline]
    pub fn value(&self, p: DVec3) -> f64 {
        let v = self.volume.sample(p);
        match self.scale {
            None => v,
            Some(k) => 1.0 + k * v,
        }
    }
}

/// RGB extinction `scale * value` from a VDB float grid (a density grid).
#[derive(Clone, Debug)]
pub struct GridExtinction {
    /// The grid.
    pub volume: Arc<FloatVolume>,
    /// sigma_t per unit of the grid's value, RGB, per world unit.
    pub scale: DVec3,
}

impl Material {
    /// A clear, non-scattering, non-emitting medium of constant index.
    pub fn clear(n: f64) -> Self {
        Self {
            index: IndexProfile::Constant([n; 3]),
            extinction: DVec3::ZERO,
            albedo: DVec3::ZERO,
            g: 0.0,
            emission: DVec3::ZERO,
            index_grid: None,
            extinction_grid: None,
        }
    }

    /// Refractive index at `p` for colour `channel`: the profile's, or the
    /// VDB grid's when the index comes from one.
    #[inline]
    pub fn index_at(&self, p: DVec3, channel: usize) -> f64 {
        match &self.index_grid {
            Some(g) => g.value(p),
            None => self.index.value(p, channel),
        }
    }

    /// RGB extinction at `p`.
    #[inline]
    pub fn extinction_at(&self, p: DVec3) -> DVec3 {
        match &self.extinction_grid {
            Some(g) => g.scale * g.volume.sample(p),
            None => self.extinction,
        }
    }
}

/// One solid of the scene.
#[derive(Clone, Debug)]
pub struct Object {
    /// Name used in listings and errors.
    pub name: String,
    /// Where the object is.
    pub shape: Shape,
    /// What it is made of.
    pub material: Material,
    /// Overlaps go to the highest priority (Schmidt & Budge); ties go to the
    /// object listed later.
    pub priority: i64,
}
