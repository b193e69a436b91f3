//! The light volume of one light source: what the simulation stores per
//! cell, and what the renderer reads.
//!
//! # What is stored
//! * `fluence`: the RGB fluence rate `phi` per cell, the cell average of
//!   `int L dw` over all directions, in W per scene unit^2 (flux per area
//!   when the scene's unit is the metre). It is what a track-length
//!   estimator measures: every piece of a beam of flux `P` that runs a length
//!   `l` through a cell of volume `V` adds `P l / V`, so where ray families
//!   overlap (behind a caustic) they add up. For light from one direction
//!   it is the irradiance across the beam.
//! * `flux`: the net flux vector `F = int L w dw` per cell (the vector
//!   irradiance, the first angular moment), W per scene unit^2; each piece
//!   adds `P l d / V` with `d` its unit direction. Without dispersion one
//!   array holding the mean of the three colour channels' vectors; with
//!   dispersion three, one per channel (each channel is its own ray
//!   family).
//!
//! For one ray family `|F| = phi` and `F / |F|` is its direction. A renderer
//! turns the pair into in-scattered radiance per unit length of the eye
//! ray as `albedo sigma_t phi p_HG(w . l; g mu)` with `l = F / |F|` and the
//! mean cosine `mu = |F| / phi` (Henyey-Greenstein's angular moments are
//! `g^k`, so the first moment of the in-scatter is exact whatever the mix
//! of directions, and the whole of it for one family). A surface of normal
//! `N` facing the light receives the irradiance `max(0, -F . N)`.
//!
//! `--deposit paper` [Ihrke07 sec 5.2.2] stores its highest-energy
//! ray in the same form: `phi` its differential irradiance, `F` that times
//! its direction (`mu = 1`).

use eikon_grid::GridGeometry;
use ndarray::Array4;

/// The light volume of one light source (see the module docs).
#[derive(Clone, Debug)]
pub struct LightVolume {
    /// RGB fluence rate per cell, W per scene unit^2, `(nx, ny, nz, 3)`.
    pub fluence: Array4<f32>,
    /// Net flux vector per cell, W per scene unit^2, `(nx, ny, nz, 3)`:
    /// one array (the mean over the colour channels), or three (R, G, B)
    /// when the light was traced with dispersion.
    pub flux: Vec<Array4<f32>>,
}

impl LightVolume {
    /// A finished light volume from its arrays (read back from disk, say):
    /// `fluence` `(nx, ny, nz, 3)`, and one or three `flux` arrays of the
    /// same shape. Errors name the array whose shape is wrong.
    pub fn from_arrays(
        grid: &GridGeometry,
        fluence: Array4<f32>,
        flux: Vec<Array4<f32>>,
    ) -> Result<Self, String> {
        let [nx, ny, nz] = grid.dims;
        let want = [nx, ny, nz, 3];
        if fluence.shape() != want {
            return Err(format!(
                "fluence has shape {:?}, the grid needs {want:?}",
                fluence.shape()
            ));
        }
        if !(flux.len() == 1 || flux.len() == 3) {
            return Err(format!(
                "{} flux arrays: need 1, or 3 with dispersion",
                flux.len()
            ));
        }
        if let Some(d) = flux.iter().find(|d| d.shape() != want) {
            return Err(format!(
                "flux has shape {:?}, the grid needs {want:?}",
                d.shape()
            ));
        }
        Ok(Self {
            fluence: fluence.as_standard_layout().into_owned(),
            flux: flux
                .into_iter()
                .map(|d| d.as_standard_layout().into_owned())
                .collect(),
        })
    }

    /// One ray family per cell (the paper's highest-energy ray): RGB
    /// differential irradiance `irradiance` and unit `direction` per wavefront
    /// group. Fluence is the irradiance, the flux vector that times the
    /// direction (for each group, the mean over the colour channels without
    /// dispersion, the group's channel with it).
    pub fn from_rays(irradiance: Array4<f32>, direction: Vec<Array4<f32>>) -> Self {
        let groups = direction.len();
        let flux = direction
            .into_iter()
            .enumerate()
            .map(|(g, mut d)| {
                ndarray::Zip::from(d.lanes_mut(ndarray::Axis(3)))
                    .and(irradiance.lanes(ndarray::Axis(3)))
                    .for_each(|mut d, e| {
                        let s = if groups == 3 {
                            e[g]
                        } else {
                            (e[0] + e[1] + e[2]) / 3.0
                        };
                        d.mapv_inplace(|x| x * s);
                    });
                d
            })
            .collect();
        Self {
            fluence: irradiance,
            flux,
        }
    }

    /// The flux array that colour channel `ch` reads.
    pub fn flux_of(&self, ch: usize) -> &Array4<f32> {
        &self.flux[ch.min(self.flux.len() - 1)]
    }
}

/// The mean cosine `mu = |F| / phi` of a cell's light (1 for one ray
/// family, less where directions mix, 0 for none), from the RGB fluence
/// `phi` and the flux vector `flux` of channel `ch` of a volume with
/// `arrays` flux arrays: with dispersion channel `ch`'s own fluence goes
/// with its vector, else the mean of the three.
#[inline]
pub fn mean_cosine(phi: [f64; 3], flux: f64, ch: usize, arrays: usize) -> f64 {
    let family = if arrays == 3 {
        phi[ch]
    } else {
        (phi[0] + phi[1] + phi[2]) / 3.0
    };
    if family > 0.0 {
        (flux / family).min(1.0)
    } else {
        0.0
    }
}
