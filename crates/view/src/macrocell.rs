//! Empty-space skipping for eye rays: a coarse grid of macro-cells
//! (blocks of `BLOCK^3` voxels) that marks where the medium is uniform for
//! the image formation model. In such a block, out to one voxel beyond it,
//! the index is one constant with zero gradient, nothing scatters or
//! emits, no boundary reflects, and the extinction is one constant per
//! channel. Any trilinear sample taken inside the block sees exactly
//! those values, so an eye ray crosses it in one straight step and eq 5's
//! attenuation over that step is exactly `exp(-sigma_t length)`.
//!
//! Clear air is the common case; the homogeneous interior of a glass
//! object (absorbing, not scattering) is the other.

use eikon_grid::Medium;
use glam::DVec3;
use rayon::prelude::*;

/// Edge of a macro-cell, voxels.
pub const BLOCK: usize = 4;

/// What a ray needs to cross a uniform block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Uniform {
    /// The block's refractive index.
    pub n: f64,
    /// Its RGB extinction, per world unit.
    pub sigma: DVec3,
}

/// The macro-cell grid of one index channel of a medium.
#[derive(Clone, Debug)]
pub struct MacroCells {
    dims: [usize; 3],
    min: DVec3,
    inv_block: DVec3,
    /// Per block: `[n, sigma_r, sigma_g, sigma_b]`, with `n` NaN where the
    /// block is not uniform.
    cells: Vec<[f32; 4]>,
}

impl MacroCells {
    /// The macro-cells of index channel `channel` of `medium`.
    pub fn new(medium: &Medium, channel: usize) -> Self {
        let g = &medium.geometry;
        let dims = g.dims.map(|d| d.div_ceil(BLOCK));
        let idx = &medium.index[channel];
        let mut cells = vec![[f32::NAN; 4]; dims[0] * dims[1] * dims[2]];
        // Rounding leaves the smoothed index of a homogeneous interior a
        // few ulps off its value, and the smoothing's tails leave gradients
        // and boundary values a few voxels from a surface. Below `tiny`
        // they turn a ray by under 1e-4 radians across a block and reflect
        // under 1e-4 of one interface crossing: nothing a pixel shows.
        let tiny = (1e-4 / (BLOCK as f64 * g.voxel_size())) as f32;
        cells.par_iter_mut().enumerate().for_each(|(flat, out)| {
            let (bi, bj, bk) = (
                flat / (dims[1] * dims[2]),
                (flat / dims[2]) % dims[1],
                flat % dims[2],
            );
            let span = |b: usize, a: usize| {
                (b * BLOCK).saturating_sub(1)..((b + 1) * BLOCK + 1).min(g.dims[a])
            };
            let (i0, j0, k0) = (bi * BLOCK, bj * BLOCK, bk * BLOCK);
            let n0 = idx[[i0, j0, k0, 0]];
            let s0 = [0, 1, 2].map(|c| medium.extinction[[i0, j0, k0, c]]);
            let same = |a: f32, b: f32| (a - b).abs() <= 4.0 * f32::EPSILON * b.abs();
            for i in span(bi, 0) {
                for j in span(bj, 1) {
                    for k in span(bk, 2) {
                        let uniform = same(idx[[i, j, k, 0]], n0)
                            && (1..4).all(|c| idx[[i, j, k, c]].abs() <= tiny)
                            && medium.boundary[[i, j, k]] <= tiny
                            && (0..3).all(|c| {
                                same(medium.extinction[[i, j, k, c]], s0[c])
                                    && medium.emission[[i, j, k, c]] == 0.0
                                    && medium.extinction[[i, j, k, c]] * medium.albedo[[i, j, k, c]]
                                        == 0.0
                            });
                        if !uniform {
                            return;
                        }
                    }
                }
            }
            *out = [n0, s0[0], s0[1], s0[2]];
        });
        Self {
            dims,
            min: g.min,
            inv_block: 1.0 / (g.spacing() * BLOCK as f64),
            cells,
        }
    }

    /// If `p` lies in a uniform block: the block's medium and the distance
    /// along the unit `d` from `p` to where the line leaves the block.
    #[inline]
    pub fn crossing(&self, p: DVec3, d: DVec3) -> Option<(Uniform, f64)> {
        let u = (p - self.min) * self.inv_block;
        if !(u.x >= 0.0 && u.y >= 0.0 && u.z >= 0.0) {
            return None;
        }
        let (i, j, k) = (u.x as usize, u.y as usize, u.z as usize);
        if i >= self.dims[0] || j >= self.dims[1] || k >= self.dims[2] {
            return None;
        }
        let c = self.cells[(i * self.dims[1] + j) * self.dims[2] + k];
        if c[0].is_nan() {
            return None;
        }
        let cell = DVec3::new(i as f64, j as f64, k as f64);
        let du = d * self.inv_block;
        let mut t = f64::INFINITY;
        for a in 0..3 {
            if du[a] > 0.0 {
                t = t.min((cell[a] + 1.0 - u[a]) / du[a]);
            } else if du[a] < 0.0 {
                t = t.min((cell[a] - u[a]) / du[a]);
            }
        }
        let uniform = Uniform {
            n: c[0] as f64,
            sigma: DVec3::new(c[1] as f64, c[2] as f64, c[3] as f64),
        };
        Some((uniform, t.max(0.0)))
    }

    /// Fraction of blocks that are uniform.
    pub fn uniform_fraction(&self) -> f64 {
        let n = self.cells.iter().filter(|c| !c[0].is_nan()).count();
        n as f64 / self.cells.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use eikon_grid::Scene;

    #[test]
    fn clear_air_and_a_glass_interior_are_uniform_and_the_surface_is_not() {
        let scene = Scene::parse(
            r#"
[grid]
resolution = 32
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = 0.85 }
index = 1.5
extinction = [0.5, 1, 2]
"#,
            "test",
        )
        .unwrap();
        let m = Medium::build(&scene).unwrap();
        let cells = MacroCells::new(&m, 0);
        let (inside, t) = cells
            .crossing(DVec3::new(0.01, 0.01, 0.01), DVec3::X)
            .unwrap();
        assert!((inside.n - 1.5).abs() < 1e-6);
        assert!((inside.sigma - DVec3::new(0.5, 1.0, 2.0)).length() < 1e-5);
        // From the block's corner region to its +x face: under a block.
        assert!(t > 0.0 && t <= 0.25 + 1e-12, "{t}");
        let (air, _) = cells
            .crossing(DVec3::new(0.95, 0.95, 0.95), DVec3::X)
            .unwrap();
        assert_eq!((air.n, air.sigma), (1.0, DVec3::ZERO));
        assert!(cells
            .crossing(DVec3::new(0.85, 0.0, 0.0), DVec3::X)
            .is_none());
        assert!(cells.crossing(DVec3::splat(2.0), DVec3::X).is_none());
        let f = cells.uniform_fraction();
        // At 32^3 the band of a surface (about 4.5 voxels either side, plus
        // the block and its margin) takes most blocks.
        assert!(f > 0.05 && f < 0.5, "{f}");
    }
}
