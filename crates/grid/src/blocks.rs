//! A coarse grid of `BLOCK^3`-voxel blocks over a medium's voxels: the
//! shared frame of empty-space skipping for light ([`crate::EmptySpace`])
//! and for eye rays (eikon-view's `MacroCells`). Block `(i, j, k)` holds
//! voxels `BLOCK i .. BLOCK (i + 1)` along x (and so on), the last block
//! of an axis fewer where `BLOCK` does not divide the voxel count; blocks
//! are stored x slowest, z fastest, as the voxels are.

use crate::geometry::GridGeometry;
use glam::DVec3;
use std::ops::Range;

/// Voxels per block edge.
pub const BLOCK: usize = 4;

/// The blocks of one grid (see the [module docs](self)).
#[derive(Clone, Debug)]
pub struct BlockGrid {
    /// Blocks per axis: `ceil(voxels / BLOCK)`.
    pub dims: [usize; 3],
    /// Voxels per axis.
    voxels: [usize; 3],
    /// The grid's lower corner.
    min: DVec3,
    /// Edge of a block, world units per axis.
    edge: DVec3,
    /// `1 / edge`.
    inv_edge: DVec3,
}

impl BlockGrid {
    /// The blocks over `grid`.
    pub fn new(grid: &GridGeometry) -> Self {
        let edge = grid.spacing() * BLOCK as f64;
        Self {
            dims: grid.dims.map(|d| d.div_ceil(BLOCK)),
            voxels: grid.dims,
            min: grid.min,
            edge,
            inv_edge: 1.0 / edge,
        }
    }

    /// Number of blocks.
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Whether there are no blocks (an empty grid).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `1 / edge`: world units to block units.
    pub fn inv_edge(&self) -> DVec3 {
        self.inv_edge
    }

    /// The grid's extent along `axis` in block units (the last block may
    /// be cut short).
    #[inline]
    pub fn extent(&self, axis: usize) -> f64 {
        self.voxels[axis] as f64 / BLOCK as f64
    }

    /// The flat index of block `[i, j, k]`.
    #[inline(always)]
    pub fn flat(&self, [i, j, k]: [usize; 3]) -> usize {
        (i * self.dims[1] + j) * self.dims[2] + k
    }

    /// The block `[i, j, k]` of flat index `flat`.
    #[inline]
    pub fn coords(&self, flat: usize) -> [usize; 3] {
        [
            flat / (self.dims[1] * self.dims[2]),
            (flat / self.dims[2]) % self.dims[1],
            flat % self.dims[2],
        ]
    }

    /// The block holding `p` and `p` in block units (`(p - min) / edge`,
    /// so the block is its integer part), or `None` outside the grid.
    #[inline(always)]
    pub fn locate(&self, p: DVec3) -> Option<([usize; 3], DVec3)> {
        let u = (p - self.min) * self.inv_edge;
        // Also rejects NaN.
        if !(u.x >= 0.0 && u.y >= 0.0 && u.z >= 0.0) {
            return None;
        }
        let b = [u.x as usize, u.y as usize, u.z as usize];
        if b[0] >= self.dims[0] || b[1] >= self.dims[1] || b[2] >= self.dims[2] {
            return None;
        }
        Some((b, u))
    }

    /// The centre of block `[i, j, k]` (of its full `BLOCK^3` extent).
    pub fn centre(&self, [i, j, k]: [usize; 3]) -> DVec3 {
        self.min + (DVec3::new(i as f64, j as f64, k as f64) + 0.5) * self.edge
    }

    /// The voxels of block `b` and a margin of one voxel around it, per
    /// axis, clipped to the grid: what a trilinear sample taken anywhere
    /// in the block can read.
    pub fn around(&self, b: [usize; 3]) -> [Range<usize>; 3] {
        [0, 1, 2]
            .map(|a| (b[a] * BLOCK).saturating_sub(1)..((b[a] + 1) * BLOCK + 1).min(self.voxels[a]))
    }

    /// The first voxel of block `b`.
    pub fn first_voxel(&self, b: [usize; 3]) -> [usize; 3] {
        b.map(|x| x * BLOCK)
    }

    /// Whether `keep(i, j, k)` holds for every voxel [`around`](Self::around)
    /// block `b`; stops at the first that fails.
    #[inline]
    pub fn all_around(
        &self,
        b: [usize; 3],
        mut keep: impl FnMut(usize, usize, usize) -> bool,
    ) -> bool {
        let [ri, rj, rk] = self.around(b);
        for i in ri {
            for j in rj.clone() {
                for k in rk.clone() {
                    if !keep(i, j, k) {
                        return false;
                    }
                }
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(dims: [usize; 3]) -> GridGeometry {
        GridGeometry::new(dims, DVec3::new(-1.0, 0.0, 2.0), DVec3::new(1.0, 3.0, 3.0))
    }

    #[test]
    fn blocks_cover_the_grid_and_locate_their_points() {
        let g = grid([10, 12, 5]);
        let b = BlockGrid::new(&g);
        assert_eq!(b.dims, [3, 3, 2]);
        assert_eq!(b.len(), 18);
        for f in 0..b.len() {
            let c = b.coords(f);
            assert_eq!(b.flat(c), f);
            // A block's centre lies in it; its first voxel's centre too.
            assert_eq!(b.locate(b.centre(c)).map(|(x, _)| x), Some(c));
            let v = b.first_voxel(c);
            let p = g.voxel_center(v[0], v[1], v[2]);
            assert_eq!(b.locate(p).map(|(x, _)| x), Some(c));
            // The margin: one voxel each side, clipped to the grid.
            let r = b.around(c);
            for a in 0..3 {
                assert_eq!(r[a].start, (c[a] * BLOCK).saturating_sub(1));
                assert_eq!(r[a].end, ((c[a] + 1) * BLOCK + 1).min(g.dims[a]));
            }
        }
        // The corner of the grid is in block 0; outside and NaN are not.
        assert_eq!(b.locate(g.min).map(|(x, _)| x), Some([0, 0, 0]));
        assert!(b.locate(g.min - 1e-9).is_none());
        assert!(b.locate(g.max + DVec3::splat(0.5)).is_none());
        assert!(b.locate(DVec3::NAN).is_none());
        // all_around visits the block and its margin, and stops early.
        let mut n = 0;
        assert!(b.all_around([1, 1, 0], |_, _, _| {
            n += 1;
            true
        }));
        assert_eq!(n, 6 * 6 * 5);
        assert!(!b.all_around([1, 1, 0], |i, _, _| i < 4));
    }
}
