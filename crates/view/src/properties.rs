//! The medium's optical properties as eye rays read them, packed per voxel
//! so that one trilinear pass over eight cells fetches everything a ray
//! step needs (as a GPU would read one RGBA texture):
//!
//! * `[sigma_t r, g, b, delta]`: extinction per world unit and the
//!   boundary indicator [Ihrke07 eqs 2, 5];
//! * `[sigma_s r, g, b, g]`: scattering `albedo * sigma_t` and the
//!   Henyey-Greenstein asymmetry [Ihrke07 eqs 2, 6];
//! * `[L_e r, g, b, 0]`: emitted radiance per unit length, stored only
//!   when the medium emits anywhere;
//! * per index channel, `[n_lo, n_hi]`: the interface sides
//!   ([`Interfaces`], shared with the light simulation), for Fresnel's n1
//!   and n2.

use eikon_grid::interface::Interfaces;
pub use eikon_grid::interface::Sides;
use eikon_grid::{GridGeometry, Medium, Trilinear};
use glam::{DVec3, Vec4};
use rayon::prelude::*;

/// What one step reads at a point.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sample {
    /// Extinction sigma_t, per world unit.
    pub sigma: DVec3,
    /// Boundary indicator delta, per world unit.
    pub delta: f64,
    /// Scattering coefficient sigma_s = albedo sigma_t, per world unit.
    pub scatter: DVec3,
    /// Henyey-Greenstein g.
    pub g: f64,
    /// Emitted radiance per unit length.
    pub emission: DVec3,
}

/// Packed optical properties of a medium (see the module docs).
pub struct Properties {
    pub(crate) texels: Vec<[Vec4; 2]>,
    pub(crate) sides: Interfaces,
    pub(crate) emission: Option<Vec<Vec4>>,
    geometry: GridGeometry,
}

impl Properties {
    /// Bytes the packed properties of a grid of `cells` voxels with
    /// `channels` index channels take, `emission` when the medium emits
    /// (for the memory estimate checked before a render).
    pub fn bytes(cells: u128, channels: usize, emission: bool) -> u128 {
        let per_cell = std::mem::size_of::<[Vec4; 2]>()
            + if emission {
                std::mem::size_of::<Vec4>()
            } else {
                0
            };
        cells * per_cell as u128 + Interfaces::bytes(cells, channels)
    }

    /// Pack `medium`; interface sides are read `probe` world units either
    /// side of each boundary voxel.
    pub fn new(medium: &Medium, probe: f64) -> Self {
        medium.expect_render_properties();
        let g = medium.geometry.clone();
        let count = g.voxel_count();
        let ext = medium.extinction.as_slice().expect("standard layout");
        let alb = medium.albedo.as_slice().expect("standard layout");
        let hg = medium.g.as_slice().expect("standard layout");
        let bnd = medium.boundary.as_slice().expect("standard layout");
        let em = medium.emission.as_slice().expect("standard layout");
        let mut texels = vec![[Vec4::ZERO; 2]; count];
        texels.par_iter_mut().enumerate().for_each(|(i, t)| {
            let s = [0, 1, 2].map(|c| ext[3 * i + c]);
            t[0] = Vec4::new(s[0], s[1], s[2], bnd[i]);
            t[1] = Vec4::new(
                s[0] * alb[3 * i],
                s[1] * alb[3 * i + 1],
                s[2] * alb[3 * i + 2],
                hg[i],
            );
        });
        let emission = em.iter().any(|&e| e != 0.0).then(|| {
            (0..count)
                .into_par_iter()
                .map(|i| Vec4::new(em[3 * i], em[3 * i + 1], em[3 * i + 2], 0.0))
                .collect()
        });
        let sides = Interfaces::new(medium, probe);
        Self {
            texels,
            sides,
            emission,
            geometry: g,
        }
    }

    /// Trilinear sample at world point `p` (the grid's cell-centre
    /// convention, edge values held in the outer half cell).
    #[inline]
    pub fn sample(&self, p: DVec3) -> Sample {
        self.sample_at(&self.geometry.trilinear(p))
    }

    /// Sample with trilinear weights already computed on this grid.
    #[inline]
    pub fn sample_at(&self, t: &Trilinear) -> Sample {
        let mut a = Vec4::ZERO;
        let mut b = Vec4::ZERO;
        let mut e = Vec4::ZERO;
        for k in 0..8 {
            let w = t.weight[k] as f32;
            let texel = &self.texels[t.cell[k]];
            a += texel[0] * w;
            b += texel[1] * w;
            if let Some(em) = &self.emission {
                e += em[t.cell[k]] * w;
            }
        }
        Sample {
            sigma: a.truncate().as_dvec3(),
            delta: a.w as f64,
            scatter: b.truncate().as_dvec3(),
            g: b.w as f64,
            emission: e.truncate().as_dvec3(),
        }
    }
}

impl Properties {
    /// The interface sides of index channel `ch` with trilinear weights
    /// already computed.
    #[inline]
    pub fn sides_at(&self, t: &Trilinear, ch: usize) -> Sides {
        self.sides.sides_at(t, ch)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use eikon_grid::Scene;

    #[test]
    fn packed_samples_equal_the_medium_fields() {
        let scene = Scene::parse(
            r#"
[grid]
resolution = 20
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0.1, 0, 0], radius = 0.6 }
index = 1.4
extinction = [0.5, 1, 2]
albedo = [0.2, 0.4, 0.8]
g = 0.3
emission = [0.1, 0.2, 0.3]
"#,
            "test",
        )
        .unwrap();
        let m = Medium::build(&scene).unwrap();
        let props = Properties::new(&m, 0.5);
        for p in [
            DVec3::new(0.1, 0.05, -0.02),
            DVec3::new(0.68, 0.1, 0.0),
            DVec3::new(-0.9, 0.9, 0.95),
        ] {
            let s = props.sample(p);
            let t = m.geometry.trilinear(p);
            let sigma = t.vec3(m.extinction.as_slice().unwrap());
            assert!((s.sigma - sigma).length() < 1e-5, "{p}");
            assert!((s.emission - t.vec3(m.emission.as_slice().unwrap())).length() < 1e-5);
            assert!((s.delta - t.scalar(m.boundary.as_slice().unwrap())).abs() < 1e-4);
            assert!((s.g - t.scalar(m.g.as_slice().unwrap())).abs() < 1e-6);
        }
        // At the surface, the sides read the two plateaus.
        let surface = DVec3::new(0.7, 0.0, 0.0);
        let sides = props.sides_at(&m.geometry.trilinear(surface), 0);
        assert!(
            (sides.lo - 1.0).abs() < 1e-3 && (sides.hi - 1.4).abs() < 1e-3,
            "{sides:?}"
        );
        // Deep inside: sigma_s = albedo sigma_t.
        let s = props.sample(DVec3::new(0.1, 0.0, 0.0));
        assert!((s.scatter - DVec3::new(0.1, 0.4, 1.6)).length() < 1e-5);
    }

    #[test]
    #[should_panic(expected = "render properties were released")]
    fn a_medium_for_the_light_alone_is_refused() {
        let scene = Scene::parse(
            "[grid]\nresolution = 8\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n",
            "test",
        )
        .unwrap();
        let mut m = Medium::build(&scene).unwrap();
        m.release_render_properties();
        Properties::new(&m, 0.5);
    }
}
