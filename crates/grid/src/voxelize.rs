//! Anti-aliased rasterization of a scene onto a (padded) voxel grid.
//!
//! Each cell's centre is classified with the shapes' distance bounds. A cell
//! no surface can cross (every |distance| exceeds the half-diagonal) takes
//! the owning material at its centre. A cell a surface may cross is
//! supersampled `s^3` times; each sub-sample is given to the highest-priority
//! object containing it (Schmidt & Budge) and the cell stores the mean of the
//! sub-samples' properties, plus the fraction covered by every material.

use crate::field::BuildProgress;
use crate::geometry::GridGeometry;
use crate::object::Material;
use crate::scene::Scene;
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// Per-cell raw properties, interleaved: `[n_0..n_c, ext3, alb3, g, emi3, cov_0..cov_K]`
/// where coverage `K` (the last) is the ambient medium.
pub(crate) struct Raster {
    pub stride: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl Raster {
    pub const EXT: usize = 0;
    pub const ALB: usize = 3;
    pub const G: usize = 6;
    pub const EMI: usize = 7;
    pub const COV: usize = 10;

    /// Offset of property block `p` (one of the constants above) in a cell.
    pub fn at(&self, p: usize) -> usize {
        self.channels + p
    }
}

/// Floats per cell for a scene with `channels` index fields and `objects` objects.
pub(crate) fn stride(channels: usize, objects: usize) -> usize {
    channels + Raster::COV + objects + 1
}

fn accumulate(cell: &mut [f32], m: &Material, p: DVec3, channels: usize, w: f32, cov: usize) {
    for (c, slot) in cell.iter_mut().enumerate().take(channels) {
        *slot += w * m.index_at(p, c) as f32;
    }
    let b = channels;
    let extinction = m.extinction_at(p);
    for a in 0..3 {
        cell[b + Raster::EXT + a] += w * extinction[a] as f32;
        cell[b + Raster::ALB + a] += w * m.albedo[a] as f32;
        cell[b + Raster::EMI + a] += w * m.emission[a] as f32;
    }
    cell[b + Raster::G] += w * m.g as f32;
    cell[b + Raster::COV + cov] += w;
}

/// Rasterize `scene` on `geom` (which may extend past the scene's own grid
/// to make room for a smoothing halo).
pub(crate) fn rasterize(scene: &Scene, geom: &GridGeometry, progress: BuildProgress) -> Raster {
    let channels = scene.channels();
    let nobj = scene.objects.len();
    let stride = stride(channels, nobj);
    let [nx, ny, nz] = geom.dims;
    let h = geom.spacing();
    let half_diag = 0.5 * h.length();
    let s = scene.grid.supersample;
    let boxes: Vec<Option<(DVec3, DVec3)>> = scene
        .objects
        .iter()
        .map(|o| {
            o.shape
                .aabb()
                .map(|(a, b)| (a - DVec3::splat(half_diag), b + DVec3::splat(half_diag)))
        })
        .collect();
    let mut data = vec![0f32; nx * ny * nz * stride];
    let slabs_done = AtomicU64::new(0);
    data.par_chunks_mut(ny * nz * stride)
        .enumerate()
        .for_each(|(i, slab)| {
            // Per-slab scratch, reused for every cell: no allocation per cell.
            let mut dist = vec![f64::INFINITY; nobj];
            for j in 0..ny {
                for k in 0..nz {
                    let cell = &mut slab[(j * nz + k) * stride..][..stride];
                    let p = geom.voxel_center(i, j, k);
                    let mut near = false;
                    for (o, obj) in scene.objects.iter().enumerate() {
                        dist[o] = match boxes[o] {
                            Some((lo, hi)) if !(p.cmpge(lo).all() && p.cmple(hi).all()) => {
                                f64::INFINITY
                            }
                            _ => obj.shape.distance(p),
                        };
                        near |= dist[o].abs() < half_diag;
                    }
                    if !near {
                        let owner = scene.precedence().iter().copied().find(|&o| dist[o] < 0.0);
                        let (m, cov) = match owner {
                            Some(o) => (&scene.objects[o].material, o),
                            None => (&scene.ambient, nobj),
                        };
                        accumulate(cell, m, p, channels, 1.0, cov);
                        continue;
                    }
                    let w = 1.0 / (s * s * s) as f32;
                    for a in 0..s {
                        for b in 0..s {
                            for c in 0..s {
                                let off = (DVec3::new(a as f64, b as f64, c as f64) + 0.5)
                                    / s as f64
                                    - 0.5;
                                let q = p + off * h;
                                let (m, cov) = match scene.owner(q) {
                                    Some(o) => (&scene.objects[o].material, o),
                                    None => (&scene.ambient, nobj),
                                };
                                accumulate(cell, m, q, channels, w, cov);
                            }
                        }
                    }
                }
            }
            let done = slabs_done.fetch_add(1, Ordering::Relaxed) + 1;
            progress("voxelizing", done, nx as u64);
        });
    Raster {
        stride,
        channels,
        data,
    }
}
