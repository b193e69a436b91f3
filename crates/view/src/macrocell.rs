//! Empty-space skipping for eye rays: a coarse grid of macro-cells
//! (blocks of `BLOCK^3` voxels, [`BlockGrid`]) that marks where the
//! medium is uniform for the image formation model. In such a block, out
//! to one voxel beyond it, the index is one constant with zero gradient,
//! nothing scatters or emits, no boundary reflects, and the extinction is
//! one constant per channel. Any trilinear sample taken inside the block
//! sees exactly those values, so an eye ray crosses it in one straight
//! step and [Ihrke07 eq 5]'s attenuation over that step is exactly
//! `exp(-sigma_t length)`.
//!
//! Clear air is the common case; the homogeneous interior of a glass
//! object (absorbing, not scattering) is the other.

use eikon_grid::blocks::{BlockGrid, BLOCK};
use eikon_grid::Medium;
use glam::DVec3;
use rayon::prelude::*;

/// What a ray needs to cross a uniform block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Uniform {
    /// The block's refractive index.
    pub n: f64,
    /// Its RGB extinction, per world unit.
    pub sigma: DVec3,
}

/// Largest clear distance stored, voxels.
const CLEAR_CAP: u8 = 16;

/// The macro-cell grid of one index channel of a medium, and a finer
/// clear-distance field for the non-uniform blocks.
#[derive(Clone, Debug)]
pub struct MacroCells {
    /// The blocks.
    pub(crate) blocks: BlockGrid,
    /// The grid's lower corner, the voxel grid size, and per voxel the
    /// Chebyshev distance (in voxels, capped) to the nearest voxel that is
    /// not clear: within it the medium is one uniform constant (see
    /// [`MacroCells::clear_step`]).
    min: DVec3,
    voxel_dims: [usize; 3],
    inv_spacing: DVec3,
    voxel: f64,
    pub(crate) clear: Vec<u8>,
    /// Per block: `[n, sigma_r, sigma_g, sigma_b]`, with `n` NaN where the
    /// block is not uniform.
    pub(crate) cells: Vec<[f32; 4]>,
}

impl MacroCells {
    /// The macro-cells of index channel `channel` of `medium`.
    pub fn new(medium: &Medium, channel: usize) -> Self {
        medium.expect_render_properties();
        let g = &medium.geometry;
        let blocks = BlockGrid::new(g);
        let idx = &medium.index[channel];
        let mut cells = vec![[f32::NAN; 4]; blocks.len()];
        // Rounding leaves the smoothed index of a homogeneous interior a
        // few ulps off its value, and the smoothing's tails leave gradients
        // and boundary values a few voxels from a surface. Below `tiny`
        // they turn a ray by under 1e-4 radians across a block and reflect
        // under 1e-4 of one interface crossing: nothing a pixel shows.
        let tiny = (1e-4 / (BLOCK as f64 * g.voxel_size())) as f32;
        cells.par_iter_mut().enumerate().for_each(|(flat, out)| {
            let b = blocks.coords(flat);
            let [i0, j0, k0] = blocks.first_voxel(b);
            let n0 = idx[[i0, j0, k0, 0]];
            let s0 = [0, 1, 2].map(|c| medium.extinction[[i0, j0, k0, c]]);
            let same = |a: f32, b: f32| (a - b).abs() <= 4.0 * f32::EPSILON * b.abs();
            let uniform = |i: usize, j: usize, k: usize| {
                same(idx[[i, j, k, 0]], n0)
                    && (1..4).all(|c| idx[[i, j, k, c]].abs() <= tiny)
                    && medium.boundary[[i, j, k]] <= tiny
                    && (0..3).all(|c| {
                        same(medium.extinction[[i, j, k, c]], s0[c])
                            && medium.emission[[i, j, k, c]] == 0.0
                            && medium.extinction[[i, j, k, c]] * medium.albedo[[i, j, k, c]] == 0.0
                    })
            };
            if blocks.all_around(b, uniform) {
                *out = [n0, s0[0], s0[1], s0[2]];
            }
        });
        Self {
            blocks,
            cells,
            min: g.min,
            voxel_dims: g.dims,
            inv_spacing: 1.0 / g.spacing(),
            voxel: g.voxel_size(),
            clear: clear_distance(medium, channel, tiny),
        }
    }

    /// A straight step from `p` that stays in one uniform region: if the
    /// voxel holding `p` is at least 4 voxels (Chebyshev) from anything not
    /// clear, its length `(distance - 3)` voxels keeps every trilinear
    /// sample along it (one voxel of footprint, one of rounding the start
    /// down to its voxel) among clear voxels, which all hold one value.
    #[inline]
    pub fn clear_step(&self, p: DVec3) -> Option<f64> {
        let u = (p - self.min) * self.inv_spacing;
        if !(u.x >= 0.0 && u.y >= 0.0 && u.z >= 0.0) {
            return None;
        }
        let (i, j, k) = (u.x as usize, u.y as usize, u.z as usize);
        let [nx, ny, nz] = self.voxel_dims;
        if i >= nx || j >= ny || k >= nz {
            return None;
        }
        let d = self.clear[(i * ny + j) * nz + k];
        (d >= 4).then(|| (d - 3) as f64 * self.voxel)
    }

    /// If `p` lies in a uniform block: the block's medium and the distance
    /// along the unit `d` from `p` to where the line leaves the block.
    #[inline]
    pub fn crossing(&self, p: DVec3, d: DVec3) -> Option<(Uniform, f64)> {
        let ([i, j, k], u) = self.blocks.locate(p)?;
        let c = self.cells[self.blocks.flat([i, j, k])];
        if c[0].is_nan() {
            return None;
        }
        let cell = DVec3::new(i as f64, j as f64, k as f64);
        let du = d * self.blocks.inv_edge();
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

    /// Fraction of voxels from which [`Self::clear_step`] moves.
    pub fn clear_fraction(&self) -> f64 {
        self.clear.iter().filter(|&&d| d >= 4).count() as f64 / self.clear.len() as f64
    }

    /// Fraction of blocks that are uniform.
    pub fn uniform_fraction(&self) -> f64 {
        let n = self.cells.iter().filter(|c| !c[0].is_nan()).count();
        n as f64 / self.cells.len() as f64
    }
}

/// Per voxel, the Chebyshev distance (capped at [`CLEAR_CAP`]) to the
/// nearest voxel that is not clear. A voxel is clear when nothing in it
/// bends, reflects, scatters or emits (gradient and boundary under `tiny`)
/// and its index and extinction equal those of its six neighbours, so that
/// clear voxels connected through clear voxels share one value. The
/// transform is separable for the Chebyshev metric: a 1-D distance along
/// x, then `min max(|dy|, d)` along y, then along z.
fn clear_distance(medium: &Medium, channel: usize, tiny: f32) -> Vec<u8> {
    let [nx, ny, nz] = medium.geometry.dims;
    let idx = &medium.index[channel];
    let ext = &medium.extinction;
    let same = |a: f32, b: f32| (a - b).abs() <= 4.0 * f32::EPSILON * b.abs();
    let mut d = vec![0u8; nx * ny * nz];
    d.par_iter_mut().enumerate().for_each(|(f, out)| {
        let (i, j, k) = (f / (ny * nz), (f / nz) % ny, f % nz);
        let here = |i: usize, j: usize, k: usize| {
            (idx[[i, j, k, 0]], [0, 1, 2].map(|c| ext[[i, j, k, c]]))
        };
        let (n0, s0) = here(i, j, k);
        let mut clear = (1..4).all(|c| idx[[i, j, k, c]].abs() <= tiny)
            && medium.boundary[[i, j, k]] <= tiny
            && (0..3).all(|c| {
                medium.emission[[i, j, k, c]] == 0.0 && s0[c] * medium.albedo[[i, j, k, c]] == 0.0
            });
        let neighbours = [
            (i.wrapping_sub(1), j, k),
            (i + 1, j, k),
            (i, j.wrapping_sub(1), k),
            (i, j + 1, k),
            (i, j, k.wrapping_sub(1)),
            (i, j, k + 1),
        ];
        for (a, b, c) in neighbours {
            if clear && a < nx && b < ny && c < nz {
                let (n1, s1) = here(a, b, c);
                clear = same(n1, n0) && (0..3).all(|ch| same(s1[ch], s0[ch]));
            }
        }
        *out = if clear { CLEAR_CAP } else { 0 };
    });
    // One axis at a time: out[x] = min over |dx| <= cap of max(|dx|, in[x + dx]).
    let pass = |d: &mut Vec<u8>, axis: usize| {
        let len = [nx, ny, nz][axis];
        let stride = [ny * nz, nz, 1][axis];
        let src = d.clone();
        d.par_iter_mut().enumerate().for_each(|(f, out)| {
            let pos = (f / stride) % len;
            let mut best = src[f];
            for r in 1..=CLEAR_CAP as usize {
                if r as u8 >= best {
                    break;
                }
                for q in [pos.wrapping_sub(r), pos + r] {
                    if q < len {
                        let v = src[f - pos * stride + q * stride].max(r as u8);
                        best = best.min(v);
                    }
                }
            }
            *out = best;
        });
    };
    // Outside the grid counts as clear: a ray leaving the grid stops at its
    // bounds anyway. The first pass turns 0/cap into 1-D distances.
    for axis in 0..3 {
        pass(&mut d, axis);
    }
    d
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
        // The clear distance: deep inside the glass and in the far corner
        // of the air a ray may step straight; at the surface it may not.
        let deep = cells.clear_step(DVec3::new(0.01, 0.01, 0.01)).unwrap();
        assert!(deep >= 0.0625, "{deep}");
        assert!(cells.clear_step(DVec3::new(0.85, 0.0, 0.0)).is_none());
        // Brute force: from every clear start, every voxel the step can
        // reach (and its trilinear footprint) is clear.
        let h = 0.0625;
        for (i, j, k) in [(16, 16, 16), (1, 1, 1), (30, 2, 29), (12, 20, 16)] {
            let p = m.geometry.voxel_center(i, j, k);
            if let Some(s) = cells.clear_step(p) {
                let r = (s / h).ceil() as i64 + 2;
                for a in -r..=r {
                    for b in -r..=r {
                        for c in -r..=r {
                            let (x, y, z) = (i as i64 + a, j as i64 + b, k as i64 + c);
                            if [x, y, z].iter().all(|&v| (0..32).contains(&v)) {
                                let (x, y, z) = (x as usize, y as usize, z as usize);
                                assert!(
                                    m.boundary[[x, y, z]] <= 4e-4
                                        && m.index[0][[x, y, z, 0]] == m.index[0][[i, j, k, 0]],
                                    "{i} {j} {k} reaches {x} {y} {z}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
