//! Step 4: voxelization of the wavefront (5.2.2).
//!
//! After every step each patch deposits into the cell that contains its
//! midpoint; the cells under its corners are filled too where no midpoint
//! ever reached (an oblique wavefront leaves about 7% of the cells between
//! neighbouring midpoints otherwise). A cell keeps the single ray of highest energy that reached
//! it (the paper's choice for the multi-valued light field behind a
//! caustic): its RGB differential irradiance and its unit direction.
//!
//! The value deposited is the patch's irradiance carried to the cell
//! centre, a signed distance `s` (under one cell) along its direction:
//! `flux * exp(-sigma_t s) / area(corners + s * corner directions)`, the
//! intensity law over the corners' straight rays and eq 18 with the local
//! extinction. Without it the kept value would be that of wherever in the
//! cell the patch happened to be, biased towards the side the light comes
//! from (by up to `2 h / r` for a point light at distance r).
//!
//! # What is stored
//! `irradiance` is the differential irradiance Delta E of eq 17-18 in
//! W/m^2: the power per unit area crossing a surface normal to `direction`.
//! A renderer turns it into in-scattered radiance (eqs 3-4, 6) as
//! `L_s = albedo * sigma_t * p(direction, omega) * irradiance`, with the
//! phase function `p` in 1/sr, per unit length of the eye ray.

use crate::patch::{area, Patches};
use eikon_grid::{EmptySpace, GridGeometry, Medium};
use ndarray::{Array3, Array4};
use rayon::prelude::*;

/// What one patch leaves in the volume this step.
#[derive(Clone, Copy, Debug)]
struct Deposit {
    /// Flat cell index.
    cell: u32,
    /// Energy compared by the highest-energy rule.
    key: f32,
    /// 1 for the cell under the patch's midpoint, 0 for a cell reached
    /// only by a corner: a corner deposit only fills a cell no midpoint
    /// reached.
    tier: u8,
    irradiance: [f32; 3],
    direction: [f32; 3],
}

/// Cells a patch deposits into: those holding its midpoint and its four
/// corners (a patch spans at most a cell or so, so these cover its
/// footprint; the midpoint alone would leave cells between neighbouring
/// midpoints unreached when a wavefront crosses the grid obliquely).
const CANDIDATES: usize = 5;

/// The deposits of patch `i`: its irradiance carried to the centres of
/// the cells under its midpoint and corners (see the module docs), each
/// cell once; `None` for repeats and cells outside the grid.
fn deposits_of(
    p: &Patches,
    i: usize,
    medium: &Medium,
    empty: &EmptySpace,
    group: Option<usize>,
) -> [Option<Deposit>; CANDIDATES] {
    let mut out = [None; CANDIDATES];
    let grid = &medium.geometry;
    let dims = grid.dims;
    let mid = p.midpoint(i);
    let corners = p.positions(i);
    let points = [mid, corners[0], corners[1], corners[2], corners[3]];
    let d = p.direction(i);
    let unit = [0, 1, 2, 3].map(|c| p.corner[c][i].v.normalize_or_zero());
    let ext = if empty.index_at(mid).is_some() {
        glam::DVec3::ZERO
    } else {
        medium.sample_rgb(&medium.extinction, mid)
    };
    let mut seen = [u32::MAX; CANDIDATES];
    for (slot, q) in points.iter().enumerate() {
        let u = (*q - grid.min) / grid.spacing();
        if !(u.cmpge(glam::DVec3::ZERO).all()) {
            continue;
        }
        let (x, y, z) = (u.x as usize, u.y as usize, u.z as usize);
        if x >= dims[0] || y >= dims[1] || z >= dims[2] {
            continue;
        }
        let cell = ((x * dims[1] + y) * dims[2] + z) as u32;
        if seen[..slot].contains(&cell) {
            continue;
        }
        seen[slot] = cell;
        let s = d.dot(grid.voxel_center(x, y, z) - mid);
        let moved = [0, 1, 2, 3].map(|c| corners[c] + unit[c] * s);
        let ar = area(&moved);
        if ar.is_nan() || ar <= 0.0 {
            continue;
        }
        let e = [0, 1, 2].map(|c| p.flux[i][c] * (-ext[c] * s).exp() / ar);
        let key = match group {
            None => e[0] + e[1] + e[2],
            Some(c) => e[c],
        };
        out[slot] = Some(Deposit {
            cell,
            key: key as f32,
            tier: u8::from(slot == 0),
            irradiance: e.map(|v| v as f32),
            direction: [d.x as f32, d.y as f32, d.z as f32],
        });
    }
    out
}

/// The light volume of one light source.
#[derive(Clone, Debug)]
pub struct LightVolume {
    /// RGB differential irradiance per cell, W/m^2, `(nx, ny, nz, 3)`.
    pub irradiance: Array4<f32>,
    /// Unit direction of travel per cell and index channel,
    /// `(nx, ny, nz, 3)` each: one array, or three (R, G, B) when the light
    /// was traced with dispersion.
    pub direction: Vec<Array4<f32>>,
    /// Energy of the ray kept so far, per cell and wavefront group.
    best: Vec<Array3<f32>>,
    /// Tier of the ray kept so far (see `Deposit::tier`).
    tier: Vec<Array3<u8>>,
    /// This step's deposits, reused from step to step.
    pending: Vec<[Option<Deposit>; CANDIDATES]>,
}

impl LightVolume {
    /// An empty (dark) volume on `grid` for `groups` wavefronts (1, or 3
    /// with dispersion: one per colour channel).
    pub fn new(grid: &GridGeometry, groups: usize) -> Self {
        let [nx, ny, nz] = grid.dims;
        Self {
            irradiance: Array4::zeros((nx, ny, nz, 3)),
            direction: (0..groups)
                .map(|_| Array4::zeros((nx, ny, nz, 3)))
                .collect(),
            best: (0..groups).map(|_| Array3::zeros((nx, ny, nz))).collect(),
            tier: (0..groups).map(|_| Array3::zeros((nx, ny, nz))).collect(),
            pending: Vec::new(),
        }
    }

    /// Deposit every patch of a wavefront. `group` is the wavefront's
    /// colour channel with dispersion (it writes that channel only), or
    /// `None` for a wavefront carrying all three.
    ///
    /// The deposits are computed in parallel, then applied in patch order,
    /// so the result does not depend on the number of threads.
    pub fn deposit(
        &mut self,
        p: &Patches,
        medium: &Medium,
        empty: &EmptySpace,
        group: Option<usize>,
    ) {
        (0..p.len())
            .into_par_iter()
            .map(|i| deposits_of(p, i, medium, empty, group))
            .collect_into_vec(&mut self.pending);
        let g = group.unwrap_or(0);
        let best = self.best[g].as_slice_mut().expect("contiguous");
        let tier = self.tier[g].as_slice_mut().expect("contiguous");
        let irr = self.irradiance.as_slice_mut().expect("contiguous");
        let dir = self.direction[g].as_slice_mut().expect("contiguous");
        for d in self.pending.iter().flatten().flatten() {
            let cell = d.cell as usize;
            // A midpoint beats a corner; then the highest energy; strictly
            // greater, so the first of equal rays stays.
            if d.tier < tier[cell] || (d.tier == tier[cell] && d.key <= best[cell]) {
                continue;
            }
            best[cell] = d.key;
            tier[cell] = d.tier;
            match group {
                None => irr[3 * cell..3 * cell + 3].copy_from_slice(&d.irradiance),
                Some(c) => irr[3 * cell + c] = d.irradiance[c],
            }
            dir[3 * cell..3 * cell + 3].copy_from_slice(&d.direction);
        }
    }
}
