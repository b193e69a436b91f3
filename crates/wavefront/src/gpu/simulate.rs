//! The light simulator on the GPU: every step of [`crate::simulate_light`]
//! as wgpu compute kernels (`simulate.wgsl`), with the same physics,
//! conventions and units, in f32, for both deposit rules
//! ([`DepositRule`]) and with or without Fresnel transmission. The kernel
//! source is composed ([`source`]) from the WGSL modules it shares with
//! the CPU code and the view renderer (the grid, the ray equation, Fresnel,
//! the spot cone, patch and deposit geometry, [Ihrke07 eq 18]'s step depth, the
//! HistoPyramid), its parameter block [`SimParams`] and its constants
//! generated from their Rust definitions.
//!
//! Per wavefront, emission (`light::emit`), the absorption inside a
//! point light's start sphere (and, with the fluence deposit, the chords
//! from the light to its start sphere) and the pre-step tessellation run on
//! the CPU exactly as there; the patches are then uploaded and every step
//! runs on the GPU: propagate ([Ihrke07 eqs 14-15, 18], Fresnel at interfaces) with,
//! for the fluence deposit, the tube each patch sweeps deposited in the
//! same kernel (`deposit::tube`: sub-patches followed layer by layer of
//! cells with swept box footprints, a torn patch's corner rays cut among
//! the cells by a 3D DDA, summed per cell in a small per-thread cache; one
//! step at a time, where the CPU takes runs through empty space as one
//! tube), tessellation analysis (`refine::fate`, the deposit's own
//! rules: caustics culled with the paper's only, exit when every corner
//! has left, faint and dim patches), the split grants (in patch order, by
//! the rank of each split read off a HistoPyramid of the split flags), the
//! HistoPyramid of the counts and its walk (compaction and expansion in one
//! pass; both pyramids live in one buffer and are built by the shared
//! `histopyramid` module), and, with the paper's deposit, the highest-energy rule (atomics
//! on packed keys, ties to the lowest patch index as the CPU's in-order
//! apply) and the irradiance of [Ihrke07 eq 17].
//!
//! # Steps without read-backs
//! The device schedules its own steps (issue 16): before each, a
//! one-thread kernel (`plan_step`) reads the new list's length off the
//! counts' pyramid, checks it against the lists' room and the step limit,
//! and writes the step's parameter block (copied into place by the command
//! buffer) and how many workgroups each kernel of the step runs, which
//! they are dispatched with indirectly. One submission holds many steps
//! (up to `MOST_STEPS_PER_SUBMISSION`, doubling from
//! `FIRST_STEPS_PER_SUBMISSION` while none halts) and ends with one
//! read-back of the plan's state. Where the plan halts (no patch left,
//! the step limit, a list to grow) the later steps of the submission run
//! no workgroup, and the host grows the list or ends the wavefront and
//! goes on. The kernels run in the order and on the data of one step per
//! submission, so the result is the same bit for bit.
//!
//! # Sharp interfaces
//! With [`GpuSimulator::with_regions`] (`[grid] interfaces = "sharp"`)
//! step 1 is `propagate_sharp`, [`propagate::Sharp`] on the GPU: each
//! corner steps region by region with the shared `region_step` module
//! (`eikon_grid::region::STEP_WGSL`, `Regions::step` in the equal-time
//! form, over the region table and shape data of
//! `eikon_grid::region::gpu_regions`), the flux takes each corner's
//! `(1 - R)^(1/4)`, and a torn patch is split in four where the step
//! began and traced again, recursively, down to
//! [`propagate::MAX_SPLIT_LEVEL`] levels; a torn piece no longer than the
//! smallest split goes on as a thin tube about its centre ray, and a thin
//! tube still torn is dropped and tallied as torn. On the GPU the tree of
//! quarters is traced level by level, one node per thread (a node's
//! corners derived from its patch's down its path: no stack, no saved
//! copies):
//! - pass 0 steps every patch that holds together (depositing, tallying)
//!   and marks a torn one, whose four quarters are level 1 of the
//!   frontier (their count in a HistoPyramid over the patches);
//! - per level, `plan_level` reads the frontier's length off the pyramid
//!   of the level before, `sharp_level` finds each entry's node by a walk
//!   of that pyramid and traces it without depositing, writing 4 (torn:
//!   its quarters go on), 1 (it held together: a piece, passed on
//!   unchanged) or 0 (dropped), and `front_build` (one workgroup) builds
//!   the pyramid of those counts;
//! - after the last level the frontier lists every piece, patch by patch
//!   and each patch's in the CPU's depth-first order; `sharp_count` puts
//!   each torn patch's number of pieces in the pieces' pyramid over the
//!   patches, which gives them their slots after the list in patch order;
//!   `plan_pieces` reads the totals, pass 1 (`sharp_reflections`) writes
//!   the reflections of the patches that reflect and pass 2
//!   (`sharp_pieces`, one thread per piece) traces each piece again,
//!   depositing and tallying, and writes it. The torn patch's own slot
//!   ends at `analyse`.
//!
//! Where everything goes is fixed before it is written, so the result is
//! the same from run to run. A thread traces one node: llvmpipe (lavapipe)
//! ends every loop of an invocation once all of them together have run
//! 65535 iterations (`LP_MAX_TGSI_LOOP_ITERATIONS`, counted per group of
//! SIMD lanes), and a whole tree walked in one invocation ran past that
//! on meshes and solids of revolution and lost its last pieces. A
//! frontier or a list that outgrows the scratch or the live list halts
//! the plan in mid-step; the host grows them and the step goes on where
//! it stopped. A patch whose corners have all crossed a surface is split
//! by Fresnel ([`propagate::reflection`], the WGSL `patch_reflection`).
//! One whose reflection is traced adds one more piece after the list:
//! pass 0 finds that it reflects, pass 1 splits it, writes the reflection,
//! found again from the patch as pass 0 stored it, deposits its tube from
//! the surface and tallies `E_RESTORED`, the absorption beyond the surface
//! it gets back, taken off `E_ABSORBED`. Any other is split where it is
//! traced (pass 0, or pass 2 for a piece), its reflection tallied as
//! `E_REFLECTED`.
//! New corners (splits,
//! pieces) take the own index of the region where they lie, and a patch
//! whose corners lie in different regions is not split (`refine::Hold`),
//! as on the CPU. Crossings are found to `eikon_grid::region::gpu_eps` (a
//! few ulps of the scene's scale; the CPU: 1e-9 voxel) and, in a graded
//! region, cut by bisection (the CPU: false position).
//!
//! The fluence deposit adds to 64-bit fixed-point counters as
//! [`Counters`] does (fluence per cell and channel, the flux vector per
//! cell, component and wavefront group in two's complement; the same
//! scales), each as two u32 words added with a carry; the energy tallies
//! (absorbed, exited, culled, reflected, trapped, torn) are 64-bit fixed point the same
//! way. Integer addition commutes, so neither depends on the order the
//! threads run in: the volumes and the summary are the same bit for bit
//! from run to run. At the end the words are read back and added to the
//! CPU's counters (which hold the start sphere's chords), and
//! [`Counters::into_volume`] converts them as on the CPU.
//!
//! # Memory
//! The index field (with its gradient), the extinction and, with Fresnel,
//! the interface sides with the boundary indicator (one per index channel,
//! uploaded with the first simulation that asks for it) are rgba32float 3D
//! textures (no storage binding limit; 16 bytes per cell each). The light
//! volume is one storage buffer of one word per cell (`4 nx ny nz` bytes)
//! for each array: with the fluence deposit twelve (the low and the high
//! words of three fluence channels and of three flux-vector components, 48
//! bytes per cell; the flux words are read back and cleared per wavefront
//! group), with the paper's nine (keys, stamps, owners, irradiance and
//! direction, 36 bytes per cell). So a 256^3 volume (64 MiB per buffer, 768
//! MiB for the fluence counters, 256 MiB per texture) fits lavapipe's 128
//! MiB binding limit. The patch lists grow as needed up to that limit (64
//! bytes of corner positions per patch: 2M patches at 128 MiB);
//! `max_patches` is lowered to what fits, and anything that still does not
//! fit is a [`GpuError::TooLarge`]. [`GpuSimulator::device_bytes`]
//! estimates the peak from these layouts before a run; the lists are
//! sized by `max_patches`, which the grants keep them under.
//!
//! # Differences from the CPU
//! * f32 throughout the steps and the deposit (the CPU works in f64;
//!   emission and the pre-step tessellation are the CPU's, rounded once on
//!   upload, and the start sphere's chords the CPU's own units). Patches
//!   at a tessellation threshold or, with the paper's deposit, at a
//!   caustic can take the other fate, and the lists drift apart where the
//!   light field is multi-valued. With the fluence deposit every cell sums
//!   many patches, so a different tessellation moves its value a little:
//!   on the glass sphere (24^3, Fresnel) the median relative fluence
//!   difference is 5e-4 for a directional light, whose lists part behind
//!   the sphere, and 2e-6 for the point and spot lights, whose lists stay
//!   the same (numbers in `tests/gpu.rs`; 1.7e-3 at 128^3). With the
//!   paper's deposit a cell holds one ray: median relative irradiance
//!   difference 1.2e-7 on the 128^3 glass sphere, 98.8% of the cells
//!   within 1%, lists peaking at 64.6k patches against the CPU's 65.3k.
//! * A piece of a chord is summed in f32 before it is rounded to units
//!   (the CPU: f64), which moves a cell's counter by about 1e-7 of itself;
//!   `1 - exp(-x)` is a series below x = 0.01 (the CPU: `exp_m1`).
//! * Corners 1 to 3 are stored relative to corner 0, and each step moves
//!   them by the difference of their displacements: f32 rounding of the
//!   absolute positions (about 1e-5 of a voxel per step at 128^3) would
//!   otherwise wear the patches' shapes away and split a plane wave's
//!   patches at random. For what rounding is left, a patch is tessellated
//!   when its span exceeds the split size by more than 1e-5 (the CPU:
//!   1e-9).
//! * Energy tallies are exact sums of the f32 fluxes (64-bit fixed point at
//!   2^-52 of the largest channel's power); the balance holds to about
//!   1e-8 instead of 1e-15.
//! * On a software adapter (lavapipe) the fluence deposit is several times
//!   slower than the CPU backend: one thread per patch with a varying
//!   number of chords diverges on its SIMD lanes.

use crate::deposit::{self, Counters};
use crate::patch::{self, Patches};
use crate::refine::{Fate, Incident, Rules, INCIDENT_POINT, INCIDENT_SPOT, INCIDENT_UNIFORM};
use crate::{crossings_bound, power_bound, units_per_crossing, DepositRule, Summary};
use crate::{histopyramid, propagate, refine, Error, LightVolume, Options};
use eikon_gpu::{
    groups, texture_bytes, Buffer, Gpu, GpuError, Texture, DISPATCH, MIN_BUFFER_BYTES,
};
use eikon_grid::blocks::BLOCK;
use eikon_grid::geometry::GridGpu;
use eikon_grid::interface::{probe_length, Interfaces};
use eikon_grid::region::{gpu_eps, gpu_regions, RegionGpu};
use eikon_grid::{EmptySpace, Integrator, Light, Medium, Progress, Regions};
use eikon_shader::{compose, layout, Consts, Layout, VECTOR};
use glam::DVec3;
use ndarray::Array4;
use std::sync::OnceLock;

const SOURCE: &str = include_str!("simulate.wgsl");

layout! {
    /// The parameter block of the simulator's kernels (`P` in
    /// `simulate.wgsl`): what one step of one wavefront reads.
    pub struct SimParams {
        /// The grid.
        pub grid: GridGpu,
        /// Live patches (the list the kernels work on).
        pub n: u32,
        /// Patches of the list the walk reads (its pyramid's base).
        pub n_old: u32,
        /// Colour channel of a dispersive wavefront, or -1.
        pub group: i32,
        /// `INTEGRATOR_EULER`, or `INTEGRATOR_RK4` (also for
        /// Dormand-Prince, which has no GPU form).
        pub integrator: u32,
        /// Blocks of the empty-space table per axis.
        pub empty_dims: [u32; 3],
        /// [`Rules::max_depth`].
        pub max_depth: u32,
        /// `1 / block size` per axis, world units.
        pub inv_block: [f32; 3],
        /// [`Rules::max_patches`], as far as the device allows.
        pub max_patches: u32,
        /// Fluence units per watt-unit of length, per channel
        /// ([`Counters::scales`]).
        pub fl_scale: [f32; 3],
        /// Flux-vector units per watt-unit of length.
        pub flux_scale: f32,
        /// [`Incident`]: a point or spot light's position.
        pub incident_position: [f32; 3],
        /// Padding.
        pub pad3: u32,
        /// A spot light's unit axis.
        pub cone_axis: [f32; 3],
        /// `INCIDENT_UNIFORM`, `INCIDENT_POINT` or `INCIDENT_SPOT`.
        pub incident_kind: u32,
        /// The spot's half-angle, degrees.
        pub cone_angle: f32,
        /// Its falloff band, degrees.
        pub cone_falloff: f32,
        /// [`Rules::dim`].
        pub dim: f32,
        /// [`Rules::faint`].
        pub faint: f32,
        /// Equal-time step, world units of optical path.
        pub dt: f32,
        /// [`Rules::threshold`].
        pub threshold: f32,
        /// Split above this span, world units (see [`GpuSimulator`]).
        pub split_span: f32,
        /// Fixed-point scale of the energy tallies.
        pub scale: f32,
        /// The paper's deposit's phase id (midpoints; corners use
        /// `stamp + 1`).
        pub stamp: u32,
        /// 1: the track-length deposit ([`DepositRule::Fluence`]), 0: the
        /// paper's.
        pub fluence: u32,
        /// 1: Fresnel transmission at interfaces.
        pub fresnel: u32,
        /// Where the split flags' pyramid starts in the pyramid buffer.
        pub splits_base: u32,
        /// 1: sharp interfaces (`propagate_sharp` over `regions`).
        pub sharp: u32,
        /// Objects in the region table (the ambient medium follows them).
        pub region_count: u32,
        /// With sharp interfaces: the length below which two points on a
        /// ray are one (`eikon_grid::region::gpu_eps`).
        pub sharp_eps: f32,
        /// [`propagate::Sharp::min_span`].
        pub min_span: f32,
        /// With sharp interfaces: the step's patches before the torn
        /// patches' pieces join them (pass 0's).
        pub sharp_n: u32,
        /// Where the pieces' pyramid starts in the pyramid buffer.
        pub pieces_base: u32,
        /// The index channel of the wavefront (its regions' index).
        pub channel: u32,
        /// 1: the Fresnel-reflected light is traced on
        /// ([`propagate::reflection`]).
        pub reflections: u32,
        /// Entries of each of the frontier's two levels in `front` (the
        /// scratch's patches).
        pub front_cap: u32,
        /// The level of the torn patches' trees being traced (>= 1).
        pub front_level: u32,
        /// Entries of the level before it (the step's patches at level 1).
        pub front_prev: u32,
        /// Entries of the frontier at this level.
        pub front_len: u32,
        /// The torn patches' pieces (pass 2's threads).
        pub front_pieces: u32,
        /// [`Rules::corner_rays`] (infinite: never).
        pub corner_rays: f32,
        /// Padding.
        pub pad1: u32,
        /// Padding.
        pub pad2: u32,
        /// [`Incident`]: a point or spot light's power per channel, or a
        /// plane wave's irradiance.
        pub incident_power: [f32; 3],
        /// Padding.
        pub pad4: u32,
    }
}

layout! {
    /// The parameters of one reduction dispatch, or of one pass of a sharp
    /// step (`L` in `simulate.wgsl`).
    pub struct PyramidLevel {
        /// The level built (>= 1).
        pub level: u32,
        /// Which pyramid: 0 the counts', 1 the split flags', 2 the torn
        /// patches' pieces (sharp interfaces).
        pub pyramid: u32,
        /// `propagate_sharp`'s pass (`SHARP_*`).
        pub pass_id: u32,
        /// Padding.
        pub pad: u32,
    }
}

/// `propagate_sharp`'s passes (`L.pass_id`): pass 0 over the step's
/// patches, a level of the torn patches' trees, pass 1 (the reflections of
/// the patches that held together), pass 2 (the torn patches' pieces).
const SHARP_PATCHES: u32 = 0;
const SHARP_LEVEL: u32 = 1;
const SHARP_REFLECTIONS: u32 = 2;
const SHARP_PIECES: u32 = 3;

/// Energy categories of the tallies, each 64-bit fixed point per channel
/// (two words): words `2 (3 category + channel)`.
const ENERGY: [&str; 7] = [
    "E_ABSORBED",
    "E_EXITED",
    "E_CULLED",
    "E_REFLECTED",
    "E_TRAPPED",
    "E_TORN",
    // Absorption a traced reflection gets back: the patch was charged it
    // beyond the surface, which the reflected part never crossed (taken
    // off `E_ABSORBED`; `propagate::crossing_done`).
    "E_RESTORED",
];
/// Stats words after the energies: counts.
const S_EXITED: usize = 6 * ENERGY.len();
const S_ABSORBED: usize = S_EXITED + 1;
const S_CAUSTIC: usize = S_EXITED + 2;
const S_HELD: usize = S_EXITED + 3;
const S_KEPT: usize = S_EXITED + 4;
const S_SPLITS: usize = S_EXITED + 5;
const S_FAINT: usize = S_EXITED + 6;
/// Pieces torn at a sharp interface and dropped.
const S_TORN: usize = S_EXITED + 7;
/// Patches torn or reflecting in this step (cleared per step; read by
/// the plan to know whether `propagate_sharp`'s pass 1 is needed).
const S_TORN_NOW: usize = S_EXITED + 8;
/// Reflected patches traced on ([`Summary::reflections`]).
const S_REFLECTIONS: usize = S_EXITED + 9;
const STATS_WORDS: usize = S_EXITED + 10;
/// `propagate_sharp`'s pass 0 marks a patch that held together and
/// reflects (its reflection one piece after the list) with this fate.
const FATE_REFLECTS: u32 = 1 << 31;
/// `propagate_sharp`'s pass 0 marks a torn patch with this fate: its
/// pieces follow the list, its slot ends at `analyse`.
const FATE_TORN: u32 = 1 << 29;
/// A frontier entry's node (level << 16 | path) with this bit has held
/// together: a piece, passed on to the last level unchanged.
const PIECE_TAG: u32 = 1 << 30;
/// A frontier entry's node with this bit is the node as a thin tube about
/// its centre ray (`propagate::split_and_trace`).
const THIN_TAG: u32 = 1 << 28;
/// A frontier entry's node with this bit is torn and no longer than the
/// smallest split: it goes on as a thin tube at the next level
/// ([`THIN_TAG`]).
const BOTTOM_TAG: u32 = 1 << 27;
/// The plan's state (`Plan::state` in `simulate.wgsl`, words): why it
/// halted (`HALT_*`), the steps begun, the step limit, the longest list,
/// the live list (0 or 1), the two lists' and the scratch's capacities
/// (patches), whether the next step rebuilds the list (every step but a
/// wavefront's first), the paper deposit's next phase id, the length the
/// last walk wrote or would write, the list's length with the torn
/// patches' pieces, the level of the torn patches' trees `plan_level`
/// plans next, the frontier's length it halted for, and the frontier's
/// length at level 1.
const PL_HALT: usize = 0;
const PL_STEPS: usize = 1;
const PL_MAX_STEPS: usize = 2;
const PL_PEAK: usize = 3;
const PL_CUR: usize = 4;
const PL_CAP: usize = 5;
const PL_SCRATCH: usize = 7;
const PL_REBUILD: usize = 8;
const PL_STAMP: usize = 9;
const PL_TOTAL: usize = 10;
const PL_LEN: usize = 11;
const PL_LEVEL: usize = 12;
const PL_FRONT: usize = 13;
const PL_DESCENT: usize = 14;
const PLAN_STATE: usize = 16;
/// Why the plan halted: not at all (the submission's steps all ran), no
/// patch left, the step limit reached, no room for the next list, no
/// room for the torn patches' pieces, no room for a level of their trees.
const HALT_NONE: u32 = 0;
const HALT_DONE: u32 = 1;
const HALT_LIMIT: u32 = 2;
const HALT_ROOM: u32 = 3;
const HALT_PIECES: u32 = 4;
const HALT_FRONTIER: u32 = 5;
/// The plan's dispatch slots (three words each): the walk, the kernels
/// over the step's list, the reductions of a pyramid over it (levels 1 to
/// `MAX_LEVELS - 1`), a level of the torn patches' trees (`sharp_level`)
/// and its pyramid (`front_build`), `sharp_count`, pass 1
/// (`sharp_reflections`), pass 2 (`sharp_pieces`), the kernels over the
/// list with the pieces, and the reductions over that.
const A_REBUILD: usize = 0;
const A_N: usize = 1;
const A_LEVELS_N: usize = 2;
const A_FRONT: usize = A_LEVELS_N + MAX_LEVELS - 1;
const A_BUILD: usize = A_FRONT + 1;
const A_COUNT: usize = A_BUILD + 1;
const A_PASS1: usize = A_COUNT + 1;
const A_PIECES: usize = A_PASS1 + 1;
const A_LEN: usize = A_PIECES + 1;
const A_LEVELS_LEN: usize = A_LEN + 1;
const PLAN_SLOTS: usize = A_LEVELS_LEN + MAX_LEVELS - 1;
/// Byte offsets of `Plan::params` and `Plan::args`, and its size.
const PLAN_PARAMS_AT: u64 = PLAN_STATE as u64 * 4;
const PLAN_ARGS_AT: u64 = PLAN_PARAMS_AT + std::mem::size_of::<SimParams>() as u64;
const PLAN_BYTES: u64 = (PLAN_ARGS_AT + PLAN_SLOTS as u64 * 12).next_multiple_of(16);
/// Steps the first submission of a wavefront holds; each that runs all
/// its steps doubles the next, up to `MOST_STEPS_PER_SUBMISSION`.
const FIRST_STEPS_PER_SUBMISSION: usize = 8;
const MOST_STEPS_PER_SUBMISSION: usize = 64;
/// Cells a thread sums before its atomic adds (a list, where the CPU's
/// `deposit::Tile` holds a layer: private memory per thread is small).
const LOCAL_CELLS: u32 = 16;

fn declarations() -> String {
    let mut c = Consts::new();
    for (k, name) in ENERGY.iter().enumerate() {
        c = c.u32(name, k as u32);
    }
    let c = c
        .u32("S_EXITED", S_EXITED as u32)
        .u32("S_ABSORBED", S_ABSORBED as u32)
        .u32("S_CAUSTIC", S_CAUSTIC as u32)
        .u32("S_HELD", S_HELD as u32)
        .u32("S_KEPT", S_KEPT as u32)
        .u32("S_SPLITS", S_SPLITS as u32)
        .u32("S_FAINT", S_FAINT as u32)
        .u32("S_TORN", S_TORN as u32)
        .u32("S_TORN_NOW", S_TORN_NOW as u32)
        .u32("S_REFLECTIONS", S_REFLECTIONS as u32)
        .f32("REACH_SPANS", propagate::REACH_SPANS as f32)
        .f32("REFLECT_MIN", propagate::REFLECT_MIN as f32)
        .u32("SHARP_PATCHES", SHARP_PATCHES)
        .u32("SHARP_LEVEL", SHARP_LEVEL)
        .u32("SHARP_REFLECTIONS", SHARP_REFLECTIONS)
        .u32("SHARP_PIECES", SHARP_PIECES)
        .u32("FATE_REFLECTS", FATE_REFLECTS)
        .u32("FATE_TORN", FATE_TORN)
        .u32("PIECE_TAG", PIECE_TAG)
        .u32("THIN_TAG", THIN_TAG)
        .u32("BOTTOM_TAG", BOTTOM_TAG)
        .f32("THIN_SPAN", propagate::THIN_SPAN as f32)
        .u32("STATS_WORDS", STATS_WORDS as u32)
        .u32("MAX_CROSSINGS", propagate::MAX_CROSSINGS as u32)
        .u32("MAX_SPLIT_LEVEL", propagate::MAX_SPLIT_LEVEL)
        .u32("FATE_EXIT", Fate::Exit as u32)
        .u32("FATE_ABSORBED", Fate::Absorbed as u32)
        .u32("FATE_FAINT", Fate::Faint as u32)
        .u32("FATE_CAUSTIC", Fate::Caustic as u32)
        .u32("FATE_RETAIN", Fate::Retain as u32)
        .u32("FATE_SPLIT", Fate::Split as u32)
        .u32("NONE", u32::MAX)
        .u32("PL_HALT", PL_HALT as u32)
        .u32("PL_STEPS", PL_STEPS as u32)
        .u32("PL_MAX_STEPS", PL_MAX_STEPS as u32)
        .u32("PL_PEAK", PL_PEAK as u32)
        .u32("PL_CUR", PL_CUR as u32)
        .u32("PL_CAP", PL_CAP as u32)
        .u32("PL_SCRATCH", PL_SCRATCH as u32)
        .u32("PL_REBUILD", PL_REBUILD as u32)
        .u32("PL_STAMP", PL_STAMP as u32)
        .u32("PL_TOTAL", PL_TOTAL as u32)
        .u32("PL_LEN", PL_LEN as u32)
        .u32("PL_LEVEL", PL_LEVEL as u32)
        .u32("PL_FRONT", PL_FRONT as u32)
        .u32("PL_DESCENT", PL_DESCENT as u32)
        .u32("PLAN_STATE", PLAN_STATE as u32)
        .u32("HALT_NONE", HALT_NONE)
        .u32("HALT_DONE", HALT_DONE)
        .u32("HALT_LIMIT", HALT_LIMIT)
        .u32("HALT_ROOM", HALT_ROOM)
        .u32("HALT_PIECES", HALT_PIECES)
        .u32("HALT_FRONTIER", HALT_FRONTIER)
        .u32("A_REBUILD", A_REBUILD as u32)
        .u32("A_N", A_N as u32)
        .u32("A_LEVELS_N", A_LEVELS_N as u32)
        .u32("A_FRONT", A_FRONT as u32)
        .u32("A_BUILD", A_BUILD as u32)
        .u32("A_COUNT", A_COUNT as u32)
        .u32("A_PASS1", A_PASS1 as u32)
        .u32("A_PIECES", A_PIECES as u32)
        .u32("A_LEN", A_LEN as u32)
        .u32("A_LEVELS_LEN", A_LEVELS_LEN as u32)
        .u32("PLAN_SLOTS", PLAN_SLOTS as u32)
        .u32("PLAN_ARGS", 3 * PLAN_SLOTS as u32)
        .u32("MAX_LEVELS", MAX_LEVELS as u32)
        .u32("LOCAL_CELLS", LOCAL_CELLS);
    format!(
        "{}{}{}",
        SimParams::declaration(),
        PyramidLevel::declaration(),
        c.wgsl()
    )
}

/// The simulator's full WGSL: its generated declarations, the shared
/// modules and `simulate.wgsl`.
pub fn source() -> String {
    compose(
        &declarations(),
        &[
            &DISPATCH,
            &VECTOR,
            &eikon_grid::geometry::WGSL,
            &eikon_grid::ray::WGSL,
            &eikon_grid::interface::WGSL,
            &eikon_optics::spot::WGSL,
            &patch::WGSL,
            &deposit::WGSL,
            &propagate::WGSL,
            &histopyramid::WGSL,
            &crate::refine::WGSL,
            &eikon_grid::region::STEP_WGSL,
        ],
        SOURCE,
    )
}

/// Bytes per patch of a list's arrays (see [`PatchSet`]): four corner
/// positions with their optical path lengths, four gradients, and the
/// flux, initial flux and irradiance (with area, depth and `Crossing::kept`).
const POS_BYTES: u64 = 64;
const VEL_BYTES: u64 = 64;
const AUX_BYTES: u64 = 48;
/// Bytes of the largest per-patch array (four corner positions).
const PATCH_BYTES: u64 = POS_BYTES;
/// Bytes per patch of the paper's deposit's scratch: each patch's five
/// deposits of a step.
const DEPOSIT_BYTES: u64 = 40;
/// Bytes per patch of the frontier of the torn patches' trees: two levels
/// of one (patch, node) entry.
const FRONT_BYTES: u64 = 16;
/// Smallest capacity of the patch lists (grown by doubling from there).
const FIRST_CAP: usize = 4096;
/// Format of the medium's textures.
const TEXEL: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
/// Storage buffers bound at once (groups 0 to 2 of `simulate.wgsl`).
const STORAGE_BUFFERS: u32 = 28;
/// Most pyramid levels (4^15 entries).
const MAX_LEVELS: usize = 16;

/// The kernels, in the order a step runs them.
#[derive(Clone, Copy)]
enum Kernel {
    /// The walk: the list the last step's grants asked for.
    Rebuild,
    /// The paper's deposit: midpoints (three passes), then corners.
    MidMax,
    MidOwner,
    MidWrite,
    CornerMax,
    CornerOwner,
    CornerWrite,
    /// Step 1 (and 2 for the paper's deposit).
    Propagate,
    /// Step 1 with the fluence deposit of each patch's tube.
    PropagateTube,
    /// Step 3: fates and tallies.
    Analyse,
    /// One pyramid level.
    Reduce,
    /// The split grants.
    Grant,
    /// The patches left at the step limit.
    CullRest,
    /// Step 1 with sharp interfaces, each of its passes (`SHARP_*`,
    /// bound as [`Run::passes`]).
    PropagateSharp,
    /// A level of the torn patches' trees: its counts' pyramid (one
    /// workgroup).
    FrontBuild,
    /// The torn patches' numbers of pieces.
    SharpCount,
}

/// The kernels with sharp interfaces only (the last of [`KERNELS`]).
const SHARP_KERNELS: usize = 3;

const KERNELS: [&str; 16] = [
    "rebuild",
    "mid_max",
    "mid_owner",
    "mid_write",
    "corner_max",
    "corner_owner",
    "corner_write",
    "propagate",
    "propagate_tube",
    "analyse",
    "reduce",
    "grant",
    "cull_rest",
    "propagate_sharp",
    "front_build",
    "sharp_count",
];

/// The plan's kernels: before a step, after the torn patches' trees of a
/// sharp one, and before each level of them.
const PLANS: [&str; 3] = ["plan_step", "plan_pieces", "plan_level"];
/// Which of [`PLANS`].
const PLAN_STEP: usize = 0;
const PLAN_PIECES: usize = 1;
const PLAN_LEVEL: usize = 2;

/// The paper's deposit's six kernels, in order.
const PAPER_DEPOSIT: [Kernel; 6] = [
    Kernel::MidMax,
    Kernel::MidOwner,
    Kernel::MidWrite,
    Kernel::CornerMax,
    Kernel::CornerOwner,
    Kernel::CornerWrite,
];

/// Storage buffers of the light volume (group 2): the paper's deposit
/// binds 9 of them, the fluence deposit's counters all 12.
const VOLUME_BUFFERS: usize = 12;
const PAPER_VOLUME_BUFFERS: usize = 9;

/// Simulate one light on the GPU: [`crate::simulate_light`]'s result
/// computed by [`GpuSimulator`] (which uploads `medium` first).
pub fn simulate_light(
    gpu: &Gpu,
    light: &Light,
    medium: &Medium,
    opts: &Options,
    progress: Progress,
) -> Result<(LightVolume, Summary), Error> {
    GpuSimulator::new(gpu, medium)?.simulate(light, opts, progress)
}

/// [`simulate_light`] with sharp interfaces when `regions` are given
/// (`[grid] interfaces = "sharp"`): [`crate::simulate_light_in`] on the
/// GPU ([`GpuSimulator::with_regions`]).
pub fn simulate_light_in<'a>(
    gpu: &'a Gpu,
    light: &Light,
    medium: &'a Medium,
    regions: Option<Regions<'a>>,
    opts: &Options,
    progress: Progress,
) -> Result<(LightVolume, Summary), Error> {
    let sim = match regions {
        Some(r) => GpuSimulator::with_regions(gpu, medium, r)?,
        None => GpuSimulator::new(gpu, medium)?,
    };
    sim.simulate(light, opts, progress)
}

/// One medium uploaded to the GPU with the simulator's kernels, to light
/// it with any number of lights.
pub struct GpuSimulator<'a> {
    gpu: &'a Gpu,
    medium: &'a Medium,
    layouts: [wgpu::BindGroupLayout; 5],
    kernels: Vec<wgpu::ComputePipeline>,
    /// [`PLANS`] (their group 3 is the plan).
    plans: [wgpu::ComputePipeline; 3],
    /// Per index channel: its texture and empty-space table.
    index: Vec<(Texture, Buffer)>,
    extinction: Texture,
    /// Per index channel, the interface sides and the boundary indicator
    /// for Fresnel, `(n_lo, n_hi, delta, 0)` per cell: uploaded with the
    /// first simulation that asks for Fresnel.
    fresnel: OnceLock<Vec<Texture>>,
    /// Bound in place of those without Fresnel.
    no_fresnel: Texture,
    /// Largest storage binding, bytes.
    binding_limit: u64,
    /// Blocks of the empty-space tables and their inverse size.
    empty_dims: [u32; 3],
    inv_block: DVec3,
    /// With sharp interfaces, the scene's regions (emission, the pre-step
    /// tessellation) and their table on the device
    /// (`eikon_grid::region::gpu_regions`); else one placeholder region.
    regions: Option<Regions<'a>>,
    table: Buffer,
    /// The regions' shape data (profiles, mesh triangles and BVH nodes).
    data: Buffer,
    /// Objects in the table (the ambient medium follows them).
    region_count: u32,
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn texture_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D3,
            multisampled: false,
        },
        count: None,
    }
}

fn too_large(what: &str, need: u64, limit: u64, hint: &str) -> GpuError {
    GpuError::TooLarge {
        what: what.to_string(),
        need,
        limit,
        hint: hint.to_string(),
    }
}

/// Upload a `(nx, ny, nz, 4)` f32 array as an rgba32float 3D texture of
/// texel `(k, j, i)` for cell `(i, j, k)`.
fn texture(gpu: &Gpu, label: &str, dims: [usize; 3], data: &[f32]) -> Texture {
    let slab = dims[1] * dims[2] * 4;
    gpu.texture_3d(label, dims, TEXEL, &|i0, i1| {
        bytemuck::cast_slice(&data[i0 * slab..i1 * slab]).to_vec()
    })
}

/// The uniform index of every empty block, or -1 (`EmptySpace`'s table,
/// read through its public lookup at each block's centre).
fn empty_table(medium: &Medium, channel: usize) -> (Vec<f32>, [u32; 3], DVec3) {
    let empty = EmptySpace::new(medium, channel);
    let blocks = empty.blocks();
    let out = (0..blocks.len())
        .map(|f| {
            let c = blocks.centre(blocks.coords(f));
            empty.index_at(c).map_or(-1.0, |n| n as f32)
        })
        .collect();
    (out, blocks.dims.map(|d| d as u32), blocks.inv_edge())
}

/// Growable GPU patch list.
struct PatchSet {
    cap: usize,
    pos: Buffer,
    vel: Buffer,
    aux: Buffer,
}

impl PatchSet {
    fn new(gpu: &Gpu, cap: usize) -> Self {
        let cap = cap.max(1) as u64;
        Self {
            cap: cap as usize,
            pos: gpu.storage_empty("patch positions", cap * POS_BYTES),
            vel: gpu.storage_empty("patch gradients", cap * VEL_BYTES),
            aux: gpu.storage_empty("patch flux", cap * AUX_BYTES),
        }
    }

    /// Device bytes of a list of `cap` patches.
    fn bytes(cap: usize) -> u64 {
        cap.max(1) as u64 * (POS_BYTES + VEL_BYTES + AUX_BYTES)
    }
}

/// Bytes of the per-patch scratch over `n` patches: the pyramids (one
/// buffer: the counts', the split flags' and, with `sharp` interfaces, the
/// torn patches' pieces'), the fates, each patch's deposits (`dep_bytes`
/// per patch) and, with `sharp` interfaces, the frontier of the torn
/// patches' trees (two levels of `n` entries).
fn scratch_bytes(n: usize, dep_bytes: u64, sharp: bool) -> [u64; 4] {
    let pyramids = if sharp { 3 } else { 2 };
    [
        pyramids * pyramid_size(n) as u64 * 4,
        n as u64 * 4,
        n as u64 * dep_bytes,
        if sharp { n as u64 * FRONT_BYTES } else { 0 },
    ]
}

/// Entries of a pyramid over `n` entries (all levels).
fn pyramid_size(n: usize) -> usize {
    pyramid_levels(n).iter().map(|&(_, len)| len).sum()
}

/// Levels of a pyramid over `n` entries (`hp_depth`), without building
/// their list: counted each time a step is encoded.
fn pyramid_depth(n: usize) -> usize {
    let mut len = n.max(1);
    let mut depth = 1;
    while len > 1 {
        len = len.div_ceil(4);
        depth += 1;
    }
    depth
}

/// `(offset, length)` of each level of a pyramid over `n` entries (the
/// `histopyramid` module's `hp_offset`, `hp_len`).
fn pyramid_levels(n: usize) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut len = n.max(1);
    let mut off = 0;
    loop {
        out.push((off, len));
        if len == 1 {
            return out;
        }
        off += len;
        len = len.div_ceil(4);
    }
}

/// Dispatch `kernel` over `items` threads.
fn dispatch(pass: &mut wgpu::ComputePass, k: &wgpu::ComputePipeline, items: usize) {
    if items == 0 {
        return;
    }
    pass.set_pipeline(k);
    let (x, y) = groups(items);
    pass.dispatch_workgroups(x, y, 1);
}

/// What one light's simulation holds on the device beside the patch lists:
/// its light volume, tallies, parameters and the plan of its steps.
struct Run {
    volume: Vec<Buffer>,
    volume_group: wgpu::BindGroup,
    stats: Buffer,
    params: Buffer,
    /// `Plan` in `simulate.wgsl`: the state the host reads back, the next
    /// parameter block and the indirect dispatches' sizes.
    plan: Buffer,
    plan_group: wgpu::BindGroup,
    /// Per pyramid (counts, then splits) and level, its parameters and their
    /// bind group (the parameters live as long as their bind groups, so the
    /// tally of live bytes is what the device holds).
    levels: [Vec<(Buffer, wgpu::BindGroup)>; 3],
    /// Per pass of `propagate_sharp` (`SHARP_*`), its parameters and bind
    /// group.
    passes: Vec<(Buffer, wgpu::BindGroup)>,
}

/// The patch lists of one wavefront (the live one and the one the walk
/// writes), their per-patch scratch, and the bind groups over them.
struct Lists {
    sets: [PatchSet; 2],
    /// The live list.
    cur: usize,
    /// The most patches a list may hold: `max_patches`, or the emitted
    /// wavefront if larger.
    most: usize,
    /// Patches the scratch holds.
    scratch_cap: usize,
    /// Scratch bytes per patch of the paper's deposits (0 for the
    /// fluence deposit).
    dep_bytes: u64,
    /// Sharp interfaces: a third pyramid (the pieces') and the frontier.
    sharp: bool,
    /// The index channel and whether Fresnel's interfaces are bound.
    channel: usize,
    fresnel: bool,
    /// The counts' pyramid from 0, the split flags' from `splits_base`.
    pyramid: Buffer,
    fates: Buffer,
    deps: Buffer,
    /// The frontier of the torn patches' trees (`front` in
    /// `simulate.wgsl`).
    front: Buffer,
    /// Group 0 (the medium and the scratch).
    medium_group: wgpu::BindGroup,
    /// Group 1, `sets[k]` to `sets[1 - k]` (empty while a list is
    /// replaced).
    patch_groups: Vec<wgpu::BindGroup>,
}

/// Where a step that the plan halted in its middle goes on, once the host
/// has made room: at a level of its torn patches' trees
/// (`HALT_FRONTIER`), or at the plan of their pieces (`HALT_PIECES`).
#[derive(Clone, Copy)]
enum Resume {
    Level(u32),
    Pieces,
}

/// How one wavefront's steps went.
#[derive(Default)]
struct Traced {
    steps: usize,
    /// The longest list.
    peak: usize,
    /// Patches alive at the step limit.
    left: usize,
}

impl Lists {
    /// Where the split flags' pyramid starts.
    fn splits_base(&self) -> u32 {
        pyramid_size(self.scratch_cap) as u32
    }

    /// Where the torn patches' extra pieces' pyramid starts.
    fn pieces_base(&self) -> u32 {
        2 * pyramid_size(self.scratch_cap) as u32
    }
}

impl<'a> GpuSimulator<'a> {
    /// Compile the kernels and upload `medium` (its index channels and
    /// extinction as 3D textures, its empty-space tables).
    pub fn new(gpu: &'a Gpu, medium: &'a Medium) -> Result<Self, GpuError> {
        let limit = gpu.device.limits().max_storage_buffer_binding_size as u64;
        Self::with_binding_limit(gpu, medium, limit)
    }

    /// [`Self::new`] with storage bindings limited to `limit` bytes (at
    /// most the device's): to exercise the splitting of large volumes on
    /// small inputs.
    pub fn with_binding_limit(
        gpu: &'a Gpu,
        medium: &'a Medium,
        limit: u64,
    ) -> Result<Self, GpuError> {
        Self::build(gpu, medium, limit, None)
    }

    /// [`Self::new`] with sharp interfaces (`[grid] interfaces = "sharp"`,
    /// [`propagate::Sharp`]): corners cross the exact surfaces of
    /// `regions`' scene, each region's own index between them, as
    /// [`crate::simulate_light_in`] on the CPU. The GPU's region table
    /// (`eikon_grid::region::gpu_regions`) holds every shape, index
    /// profile and VDB grid of the CPU's; shape data larger than a storage
    /// binding is a [`GpuError::TooLarge`].
    pub fn with_regions(
        gpu: &'a Gpu,
        medium: &'a Medium,
        regions: Regions<'a>,
    ) -> Result<Self, GpuError> {
        let limit = gpu.device.limits().max_storage_buffer_binding_size as u64;
        Self::build(gpu, medium, limit, Some(regions))
    }

    fn build(
        gpu: &'a Gpu,
        medium: &'a Medium,
        limit: u64,
        regions: Option<Regions<'a>>,
    ) -> Result<Self, GpuError> {
        if !medium.has_voxel_fields() {
            return Err(GpuError::Unsupported(
                crate::Error::NeedsVoxelFields("the GPU simulator").to_string(),
            ));
        }
        let gpu_regions = regions.as_ref().map(|r| gpu_regions(r.scene()));
        let binding_limit = Self::check_limits(gpu, medium, limit)?;
        if let Some(r) = &gpu_regions {
            if r.data_bytes() > binding_limit {
                return Err(too_large(
                    "the regions' shape data: meshes, profiles and VDB grids (bytes)",
                    r.data_bytes(),
                    binding_limit,
                    "use --backend cpu, or --interfaces smoothed",
                ));
            }
        }
        let kinds = gpu_regions
            .as_ref()
            .map(|r| eikon_grid::region::table_kinds(&r.table));
        let (layouts, kernels, plans) = Self::compile(gpu, kinds)?;
        let (_, empty_dims, inv_block) = empty_table(medium, 0);
        let (index, extinction, no_fresnel) = Self::upload_medium(gpu, medium)?;
        let region_count = gpu_regions.as_ref().map_or(0, |r| r.table.len() as u32 - 1);
        let (table, data) = gpu.checked("uploading the regions", || match &gpu_regions {
            Some(r) => (
                gpu.storage("regions", &r.table),
                gpu.storage("region shape data", &r.data),
            ),
            None => (
                gpu.storage("no regions", &[RegionGpu::default()]),
                gpu.storage("no shape data", &[[0u32; 4]]),
            ),
        })?;
        Ok(Self {
            gpu,
            medium,
            layouts,
            kernels,
            plans,
            index,
            extinction,
            fresnel: OnceLock::new(),
            no_fresnel,
            binding_limit,
            empty_dims,
            inv_block,
            regions,
            table,
            data,
            region_count,
        })
    }

    /// The device's limits against what the kernels and `medium` need;
    /// the largest storage binding the lists may use.
    fn check_limits(gpu: &Gpu, medium: &Medium, limit: u64) -> Result<u64, GpuError> {
        let limits = gpu.device.limits();
        let binding_limit = limit
            .min(limits.max_storage_buffer_binding_size as u64)
            .min(limits.max_buffer_size);
        if limits.max_storage_buffers_per_shader_stage < STORAGE_BUFFERS {
            return Err(too_large(
                "the light simulator's kernels (storage buffers per stage)",
                STORAGE_BUFFERS as u64,
                limits.max_storage_buffers_per_shader_stage as u64,
                "use --backend cpu",
            ));
        }
        let g = &medium.geometry;
        let max_dim = g.dims.iter().copied().max().unwrap_or(1) as u64;
        if max_dim > limits.max_texture_dimension_3d as u64 {
            return Err(too_large(
                "the medium's 3D textures (cells along an axis)",
                max_dim,
                limits.max_texture_dimension_3d as u64,
                "lower [grid] resolution or use --backend cpu",
            ));
        }
        let volume = g.voxel_count() as u64 * 4;
        if volume > binding_limit {
            return Err(too_large(
                "one channel of the light volume (bytes)",
                volume,
                binding_limit,
                "lower [grid] resolution or use --backend cpu",
            ));
        }
        Ok(binding_limit)
    }

    /// The bind group layouts (medium and scratch, patch lists, light
    /// volume, pyramid level, and the plan in the level's place), one
    /// pipeline per kernel of [`source`] (`propagate_sharp`, the last,
    /// only with `sharp` interfaces: it is the largest kernel to compile)
    /// and the plan's two.
    #[allow(clippy::type_complexity)]
    fn compile(
        gpu: &Gpu,
        kinds: Option<u32>,
    ) -> Result<
        (
            [wgpu::BindGroupLayout; 5],
            Vec<wgpu::ComputePipeline>,
            [wgpu::ComputePipeline; 3],
        ),
        GpuError,
    > {
        let sharp = kinds.is_some();
        let layouts = gpu.checked("light simulator layouts", || {
            let make = |label, entries: &[wgpu::BindGroupLayoutEntry]| {
                gpu.device
                    .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                        label: Some(label),
                        entries,
                    })
            };
            let mut g0 = vec![storage_entry(0, true), texture_entry(1), texture_entry(2)];
            g0.push(storage_entry(3, true));
            g0.extend((4..8).map(|b| storage_entry(b, false)));
            g0.push(texture_entry(8));
            g0.push(storage_entry(9, true));
            g0.push(storage_entry(10, false));
            g0.push(storage_entry(11, true));
            let g1: Vec<_> = (0..6).map(|b| storage_entry(b, false)).collect();
            let g2: Vec<_> = (0..VOLUME_BUFFERS as u32)
                .map(|b| storage_entry(b, false))
                .collect();
            [
                make("simulator medium", &g0),
                make("simulator patches", &g1),
                make("simulator volume", &g2),
                make("simulator level", &[storage_entry(0, true)]),
                make("simulator plan", &[storage_entry(1, false)]),
            ]
        })?;
        let kernels = gpu.checked("light simulator kernels", || {
            let module = gpu
                .device
                .create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("simulate.wgsl"),
                    source: wgpu::ShaderSource::Wgsl(
                        match kinds {
                            // Only the scene's shapes' code: drivers inline
                            // every call of the region functions.
                            Some(k) => eikon_grid::region::only_kinds(&source(), k),
                            None => source(),
                        }
                        .into(),
                    ),
                });
            // Groups 0 to 2, then the pyramid level's or the plan's.
            let with = |label, group3: usize| {
                gpu.device
                    .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                        label: Some(label),
                        bind_group_layouts: &[
                            &layouts[0],
                            &layouts[1],
                            &layouts[2],
                            &layouts[group3],
                        ],
                        push_constant_ranges: &[],
                    })
            };
            let layout = with("simulator", 3);
            let planned = with("simulator plan", 4);
            let pipeline = |entry: &str, layout: &wgpu::PipelineLayout| {
                gpu.device
                    .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                        label: Some(entry),
                        layout: Some(layout),
                        module: &module,
                        entry_point: Some(entry),
                        compilation_options: Default::default(),
                        cache: None,
                    })
            };
            let kernels = if sharp {
                &KERNELS[..]
            } else {
                &KERNELS[..KERNELS.len() - SHARP_KERNELS]
            };
            let kernels = kernels
                .iter()
                .map(|entry| pipeline(entry, &layout))
                .collect::<Vec<_>>();
            let plans = PLANS.map(|entry| pipeline(entry, &planned));
            (kernels, plans)
        })?;
        let (kernels, plans) = kernels;
        Ok((layouts, kernels, plans))
    }

    /// The medium as textures: per index channel its field and empty-space
    /// table, the extinction, and the one-texel stand-in for the
    /// interfaces.
    #[allow(clippy::type_complexity)]
    fn upload_medium(
        gpu: &Gpu,
        medium: &Medium,
    ) -> Result<(Vec<(Texture, Buffer)>, Texture, Texture), GpuError> {
        let g = &medium.geometry;
        gpu.checked("uploading the medium", || {
            let index = (0..medium.channels())
                .map(|c| {
                    let data = medium.index[c].as_slice().expect("contiguous");
                    let view = texture(gpu, "index field", g.dims, data);
                    let (table, _, _) = empty_table(medium, c);
                    (view, gpu.storage("empty space", &table))
                })
                .collect::<Vec<_>>();
            let ext = medium.extinction.as_slice().expect("contiguous");
            let mut rgba = vec![0f32; g.voxel_count() * 4];
            for (o, e) in rgba.chunks_exact_mut(4).zip(ext.chunks_exact(3)) {
                o[..3].copy_from_slice(e);
            }
            let none = texture(gpu, "no interfaces", [1, 1, 1], &[0.0; 4]);
            (index, texture(gpu, "extinction", g.dims, &rgba), none)
        })
    }

    fn kernel(&self, k: Kernel) -> &wgpu::ComputePipeline {
        &self.kernels[k as usize]
    }

    /// Most patches the lists can hold.
    pub fn patch_limit(&self) -> usize {
        (self.binding_limit / PATCH_BYTES) as usize
    }

    /// Device memory, bytes, that [`Self::new`] and then [`Self::simulate`]
    /// of any one light with `opts` hold at their peak, for a medium of
    /// `dims` cells with `channels` index channels (3 with dispersion, else
    /// 1): an upper bound of what [`Gpu::peak_bytes`] counts over them, so
    /// that a run that does not fit the device can be refused before it
    /// starts. From the layouts the code allocates with, item by item:
    ///
    /// * the medium: per index channel an rgba32float texture and an
    ///   empty-space table (one f32 per block), the extinction texture and
    ///   the one-texel stand-in for the interfaces;
    /// * with `opts.fresnel`, the interface sides, one texture per channel
    ///   (kept by the simulator for later lights);
    /// * the light volume: one u32 per cell for each of its 12 arrays
    ///   (fluence deposit) or 9 (paper's, 3 unused placeholders);
    /// * the parameters (the wavefront's, one per pyramid and level, one per pass
    ///   of a sharp step), the stats,
    ///   the plan of the steps and the placeholder
    ///   region table;
    /// * the two patch lists at `opts.max_patches` (the grants never let a
    ///   list grow past it; the device may lower it to
    ///   [`Self::patch_limit`], which only lowers the need);
    /// * the per-patch scratch at that cap: the two pyramids, the fates
    ///   and, with the paper's deposit, the deposits; with `sharp`
    ///   interfaces ([`Self::with_regions`]) a third pyramid (the torn
    ///   patches' pieces') and the frontier of their trees;
    /// * the largest transient: the old scratch while it is copied into a
    ///   larger one, or the staging buffer one volume array is read back
    ///   through.
    ///
    /// With sharp interfaces the region table (one [`RegionGpu`] per
    /// object) and its shape data, and the pieces beyond `max_patches`
    /// that torn patches add to a list (as on the CPU) are not counted.
    /// A wavefront emitted larger than `opts.max_patches` (emission checks
    /// only that it stays under `EMIT_PER_PATCH_LIMIT` times it) sizes the
    /// lists itself and is not covered. Not counted either: wgpu's own
    /// staging of uploads (at most one upload, freed once submitted) and
    /// drivers' padding.
    pub fn device_bytes(dims: [usize; 3], channels: usize, opts: &Options, sharp: bool) -> u64 {
        let cells = dims.iter().map(|&d| d as u64).product::<u64>();
        let buffer = |bytes: u64| bytes.max(MIN_BUFFER_BYTES);
        let blocks = dims
            .iter()
            .map(|&d| d.div_ceil(BLOCK) as u64)
            .product::<u64>();
        let field = texture_bytes(dims, TEXEL);
        let channels = channels as u64;
        let mut medium = channels * (field + buffer(blocks * 4));
        medium += field + texture_bytes([1, 1, 1], TEXEL);
        if opts.fresnel {
            medium += channels * field;
        }
        let fluence = opts.deposit == DepositRule::Fluence;
        let word = buffer(cells * 4);
        let volume = if fluence {
            VOLUME_BUFFERS as u64 * word
        } else {
            PAPER_VOLUME_BUFFERS as u64 * word
                + (VOLUME_BUFFERS - PAPER_VOLUME_BUFFERS) as u64 * MIN_BUFFER_BYTES
        };
        let small = buffer(SimParams::size() as u64)
            + (3 * MAX_LEVELS as u64 + 4) * PyramidLevel::size() as u64
            + buffer(RegionGpu::size() as u64)
            + buffer(STATS_WORDS as u64 * 4)
            + PLAN_BYTES;
        let cap = opts.max_patches;
        let lists = 2 * PatchSet::bytes(cap);
        let dep_bytes = if fluence { 0 } else { DEPOSIT_BYTES };
        let scratch: u64 = scratch_bytes(cap, dep_bytes, sharp)
            .into_iter()
            .map(buffer)
            .sum();
        let transient = scratch.max(word).max(PatchSet::bytes(0));
        medium + volume + small + lists + scratch + transient
    }

    fn bind(&self, layout: usize, entries: &[wgpu::BindingResource]) -> wgpu::BindGroup {
        let entries: Vec<_> = entries
            .iter()
            .enumerate()
            .map(|(i, r)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: r.clone(),
            })
            .collect();
        self.gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &self.layouts[layout],
                entries: &entries,
            })
    }

    /// The bind groups of the two lists, each read while the other is
    /// written: index `cur` reads `sets[cur]`.
    fn patch_groups(&self, sets: &[PatchSet; 2]) -> Vec<wgpu::BindGroup> {
        vec![
            self.bind_patches(&sets[0], &sets[1]),
            self.bind_patches(&sets[1], &sets[0]),
        ]
    }

    fn bind_patches(&self, src: &PatchSet, dst: &PatchSet) -> wgpu::BindGroup {
        self.bind(
            1,
            &[
                src.pos.as_entire_binding(),
                src.vel.as_entire_binding(),
                src.aux.as_entire_binding(),
                dst.pos.as_entire_binding(),
                dst.vel.as_entire_binding(),
                dst.aux.as_entire_binding(),
            ],
        )
    }

    /// The Fresnel textures of every index channel (see [`Self::fresnel`]),
    /// computed ([`Interfaces::new`], as the CPU) and uploaded on first use.
    fn fresnel_textures(&self) -> Result<&[Texture], GpuError> {
        if let Some(v) = self.fresnel.get() {
            return Ok(v);
        }
        let medium = self.medium;
        let g = &medium.geometry;
        let faces = Interfaces::new(medium, probe_length(medium));
        let boundary = medium.boundary.as_slice().expect("standard layout");
        let views = self.gpu.checked("uploading the interfaces", || {
            faces
                .sides
                .iter()
                .map(|sides| {
                    let mut rgba = vec![0f32; g.voxel_count() * 4];
                    for ((o, s), &d) in rgba.chunks_exact_mut(4).zip(sides).zip(boundary) {
                        o[..3].copy_from_slice(&[s[0], s[1], d]);
                    }
                    texture(self.gpu, "interfaces", g.dims, &rgba)
                })
                .collect::<Vec<_>>()
        })?;
        Ok(self.fresnel.get_or_init(|| views))
    }

    /// Simulate one light (see [`crate::simulate_light`]): the same
    /// wavefronts, deposit rule and Fresnel transmission as the CPU. Per
    /// wavefront group: the CPU starts the wavefront
    /// ([`crate::start_wavefront`]), the list is uploaded, the steps run on
    /// the GPU ([`Self::trace`]), and the tallies come back.
    pub fn simulate(
        &self,
        light: &Light,
        opts: &Options,
        progress: Progress,
    ) -> Result<(LightVolume, Summary), Error> {
        opts.check()?;
        let opts = &opts.settled(self.regions.is_some());
        let medium = self.medium;
        let grid = &medium.geometry;
        let ngroups = medium.channels();
        let fluence = opts.deposit == DepositRule::Fluence;
        let mut summary = Summary::default();
        let crate::Plan {
            mut rules,
            dt,
            max_steps,
        } = crate::Plan::new(light, medium, opts);
        rules.max_patches = opts.max_patches.min(self.patch_limit());
        // Sharp interfaces know both indices at each surface: Fresnel there
        // needs no interface sides.
        let faces = if opts.fresnel && self.regions.is_none() {
            Some(self.fresnel_textures()?)
        } else {
            None
        };
        // The fluence deposit's counters on the CPU: the chords from a light
        // inside the volume to its start sphere are deposited there, and
        // the GPU's counters are added to them at the end, so the
        // conversion is `Counters::into_volume` itself.
        let mut tally = fluence.then(|| {
            Counters::new(
                grid,
                ngroups,
                [power_bound(light, grid); 3],
                units_per_crossing(crossings_bound(medium, opts.step, max_steps)),
            )
        });
        let run = self.open_run(fluence);
        let mut directions = Vec::with_capacity(ngroups);
        let mut stamp = 1u32;
        let (mut p, mut next) = (Patches::default(), Patches::default());
        let mut scratch = refine::Scratch::default();
        for g in 0..ngroups {
            let (mask, group) = crate::group(g, ngroups);
            rules.incident = Incident::new(light, mask);
            // Emission, the start sphere's deposit and the pre-step
            // tessellation are the CPU's own (with sharp interfaces from
            // each region's own index, splits held across a surface).
            let field = propagate::Bounded::new(medium, g);
            let exact = self.regions.as_ref().map(|regions| propagate::RegionIndex {
                regions,
                channel: g,
            });
            let shell: &dyn eikon_grid::IndexField = match &exact {
                Some(e) => e,
                None => &field,
            };
            let straddles = |x: &[DVec3; 4]| {
                self.regions.as_ref().is_some_and(|r| {
                    let at = r.at(x[0]);
                    x[1..].iter().any(|&p| r.at(p) != at)
                })
            };
            let hold: Option<refine::Hold> = self.regions.is_some().then_some(&straddles);
            crate::start_wavefront(
                light,
                medium,
                shell,
                opts,
                &rules,
                (mask, group),
                (&mut p, &mut next, &mut scratch),
                tally.as_ref(),
                &mut summary,
                hold,
                self.regions.as_ref(),
            );
            if p.is_empty() {
                directions.push(Array4::zeros((grid.dims[0], grid.dims[1], grid.dims[2], 3)));
                continue;
            }
            if p.len() > self.patch_limit() {
                return Err(too_large(
                    "the emitted wavefront (patches)",
                    p.len() as u64,
                    self.patch_limit() as u64,
                    "raise patch-size or use --backend cpu",
                )
                .into());
            }
            let mut params = self.params(&rules, dt, opts, group, tally.as_ref(), &p);
            params.channel = g as u32;
            let mut lists = self.upload(&run, g, faces.is_some(), &p, rules.max_patches, fluence);
            self.begin_group(&run, fluence);
            let traced = self.trace(
                &run,
                &mut lists,
                (&mut params, &mut stamp),
                p.len(),
                max_steps,
                progress,
            )?;
            summary.step_limit += traced.left;
            summary.peak_patches = summary.peak_patches.max(traced.peak);
            summary.steps = summary.steps.max(traced.steps);
            self.end_group(
                &run,
                &params,
                &mut summary,
                g,
                tally.as_mut(),
                &mut directions,
            )?;
            drop(lists);
        }
        let volume = match tally {
            Some(t) => self.fluence_volume(&run, t)?,
            None => {
                let irradiance = read_rgb(self.gpu, &run.volume[3..6], grid.dims)?;
                LightVolume::from_rays(irradiance, directions)
            }
        };
        crate::check_finite(&volume, &summary)?;
        Ok((volume, summary))
    }

    /// The light volume's buffers (see `simulate.wgsl`, group 2), the
    /// tallies, the parameters and the plan of one light.
    fn open_run(&self, fluence: bool) -> Run {
        let gpu = self.gpu;
        let cells = self.medium.geometry.voxel_count() as u64;
        let vol = |label: &str| gpu.storage_empty(label, cells * 4);
        let volume: Vec<Buffer> = if fluence {
            ["fluence lo", "fluence hi", "flux lo", "flux hi"]
                .into_iter()
                .flat_map(|w| (0..3).map(move |c| (w, c)))
                .map(|(w, c)| vol(&format!("{w} {c}")))
                .collect()
        } else {
            let mut v: Vec<_> = [
                "deposit keys",
                "deposit stamps",
                "deposit owners",
                "irradiance R",
                "irradiance G",
                "irradiance B",
                "direction x",
                "direction y",
                "direction z",
            ]
            .into_iter()
            .map(vol)
            .collect();
            v.extend(
                (PAPER_VOLUME_BUFFERS..VOLUME_BUFFERS).map(|_| gpu.storage_empty("unused", 0)),
            );
            v
        };
        let volume_group = self.bind(
            2,
            &volume
                .iter()
                .map(|b| b.as_entire_binding())
                .collect::<Vec<_>>(),
        );
        let block = |label, value: PyramidLevel| {
            let u = gpu.params(label, &[value]);
            let group = self.bind(3, &[u.as_entire_binding()]);
            (u, group)
        };
        let levels = [0u32, 1, 2].map(|pyramid| {
            (0..MAX_LEVELS as u32)
                .map(|level| {
                    block(
                        "pyramid level",
                        PyramidLevel {
                            level,
                            pyramid,
                            ..Default::default()
                        },
                    )
                })
                .collect()
        });
        let passes = [SHARP_PATCHES, SHARP_LEVEL, SHARP_REFLECTIONS, SHARP_PIECES]
            .map(|pass_id| {
                block(
                    "sharp pass",
                    PyramidLevel {
                        pass_id,
                        ..Default::default()
                    },
                )
            })
            .into();
        let plan = gpu.storage_indirect("plan", PLAN_BYTES);
        let plan_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("plan"),
            layout: &self.layouts[4],
            entries: &[wgpu::BindGroupEntry {
                binding: 1,
                resource: plan.as_entire_binding(),
            }],
        });
        Run {
            volume,
            volume_group,
            stats: gpu.storage_empty("stats", STATS_WORDS as u64 * 4),
            params: gpu.params("params", &[SimParams::default()]),
            plan,
            plan_group,
            levels,
            passes,
        }
    }

    /// The parameter block of a wavefront: the grid, the rules, the
    /// incident light, the deposit's scales and the tallies' fixed point
    /// (the largest channel's power at 2^52 units).
    fn params(
        &self,
        rules: &Rules,
        dt: f64,
        opts: &Options,
        group: Option<usize>,
        tally: Option<&Counters>,
        p: &Patches,
    ) -> SimParams {
        let grid = &self.medium.geometry;
        let f3 = |v: DVec3| v.to_array().map(|x| x as f32);
        let biggest = p
            .flux
            .iter()
            .fold([0.0f64; 3], |a, f| [0, 1, 2].map(|c| a[c] + f[c]))
            .into_iter()
            .fold(0.0, f64::max)
            .max(1e-300);
        let scale = 2f64.powi((52.0 - biggest.log2().ceil()).clamp(-120.0, 120.0) as i32);
        let (fl_scale, flux_scale) = tally.map_or(([0.0; 3], 0.0), Counters::scales);
        let mut params = SimParams {
            grid: GridGpu::new(grid),
            group: group.map_or(-1, |c| c as i32),
            integrator: if opts.integrator == Integrator::Euler {
                Integrator::Euler as u32
            } else {
                Integrator::Rk4 as u32
            },
            empty_dims: self.empty_dims,
            max_depth: rules.max_depth as u32,
            inv_block: f3(self.inv_block),
            max_patches: rules.max_patches as u32,
            fl_scale: fl_scale.map(|x| x as f32),
            flux_scale: flux_scale as f32,
            incident_kind: INCIDENT_UNIFORM,
            dim: rules.dim as f32,
            faint: rules.faint as f32,
            corner_rays: rules.corner_rays as f32,
            dt: dt as f32,
            threshold: opts.threshold as f32,
            // The CPU's `span > split_span (1 + 1e-9)` with the tolerance
            // widened to f32's rounding: a patch emitted exactly at the
            // split size must not split on a rounding error.
            split_span: (rules.split_span * (1.0 + 1e-5)) as f32,
            scale: scale as f32,
            fluence: u32::from(tally.is_some()),
            fresnel: u32::from(opts.fresnel),
            reflections: u32::from(opts.fresnel && opts.reflections),
            sharp: u32::from(self.regions.is_some()),
            region_count: self.region_count,
            sharp_eps: gpu_eps(grid) as f32,
            min_span: crate::sharp_min_span(grid, opts) as f32,
            ..Default::default()
        };
        match rules.incident {
            Incident::Uniform(e) => params.incident_power = e.map(|x| x as f32),
            Incident::Point {
                position,
                power,
                cone,
            } => {
                params.incident_position = f3(position);
                params.incident_power = power.map(|x| x as f32);
                params.incident_kind = INCIDENT_POINT;
                if let Some((axis, angle, falloff)) = cone {
                    params.incident_kind = INCIDENT_SPOT;
                    params.cone_axis = f3(axis);
                    params.cone_angle = angle as f32;
                    params.cone_falloff = falloff as f32;
                }
            }
        }
        params
    }

    /// Upload the wavefront `p` of index channel `g` into new lists (never
    /// larger than `max_patches` or the emitted wavefront) with their
    /// scratch and bind groups, the interfaces bound with `fresnel`.
    fn upload(
        &self,
        run: &Run,
        g: usize,
        fresnel: bool,
        p: &Patches,
        max_patches: usize,
        fluence: bool,
    ) -> Lists {
        let gpu = self.gpu;
        let n0 = p.len();
        // With sharp interfaces the torn patches' pieces join the list
        // whatever `max_patches` says (as on the CPU): up to what the
        // device holds.
        let most = if self.regions.is_some() {
            self.patch_limit().max(n0)
        } else {
            max_patches.max(n0)
        };
        let cap = (2 * n0).max(FIRST_CAP).min(most);
        let sets = [PatchSet::new(gpu, cap), PatchSet::new(gpu, cap)];
        let mut pos = Vec::with_capacity(n0 * 16);
        let mut vel = Vec::with_capacity(n0 * 16);
        let mut aux = Vec::with_capacity(n0 * 12);
        for i in 0..n0 {
            let x0 = p.corner[0][i].x;
            for c in 0..4 {
                let r = &p.corner[c][i];
                // Corner 0 absolute, the others relative to it.
                let x = if c == 0 { x0 } else { r.x - x0 };
                pos.extend([x.x, x.y, x.z, r.opl].map(|v| v as f32));
                vel.extend([r.v.x, r.v.y, r.v.z, 0.0].map(|v| v as f32));
            }
            let (f, f0, e) = (p.flux[i], p.flux0[i], p.irradiance(i));
            aux.extend([f[0], f[1], f[2], p.area0[i]].map(|v| v as f32));
            // (Patches start on the device between crossings: their
            // region codes, `Crossing::into`, are the CPU's own.)
            debug_assert_eq!(p.crossing[i].into, 0, "uploaded mid-crossing");
            aux.extend([f0[0], f0[1], f0[2], p.depth[i] as f64].map(|v| v as f32));
            aux.extend([e[0], e[1], e[2], p.crossing[i].kept].map(|v| v as f32));
        }
        gpu.queue
            .write_buffer(&sets[0].pos, 0, bytemuck::cast_slice(&pos));
        gpu.queue
            .write_buffer(&sets[0].vel, 0, bytemuck::cast_slice(&vel));
        gpu.queue
            .write_buffer(&sets[0].aux, 0, bytemuck::cast_slice(&aux));
        let dep_bytes = if fluence { 0 } else { DEPOSIT_BYTES };
        let sharp = self.regions.is_some();
        let [pyramid, fates, deps, front] = self.scratch(cap, dep_bytes, sharp);
        let medium_group = self.bind_medium(run, g, fresnel, [&pyramid, &fates, &deps, &front]);
        let patch_groups = self.patch_groups(&sets);
        Lists {
            sets,
            cur: 0,
            most,
            scratch_cap: cap,
            dep_bytes,
            sharp,
            channel: g,
            fresnel,
            pyramid,
            fates,
            deps,
            front,
            medium_group,
            patch_groups,
        }
    }

    /// New scratch buffers over `cap` patches (see [`scratch_bytes`]).
    fn scratch(&self, cap: usize, dep_bytes: u64, sharp: bool) -> [Buffer; 4] {
        let [pb, fb, db, nb] = scratch_bytes(cap, dep_bytes, sharp);
        [
            self.gpu.storage_empty("pyramids", pb),
            self.gpu.storage_empty("fates", fb),
            self.gpu.storage_empty("deposits", db),
            self.gpu.storage_empty("frontier", nb),
        ]
    }

    /// Group 0: the medium of index channel `g` (with its interfaces when
    /// `fresnel`), the parameters, tallies and the scratch.
    fn bind_medium(
        &self,
        run: &Run,
        g: usize,
        fresnel: bool,
        [pyramid, fates, deps, front]: [&wgpu::Buffer; 4],
    ) -> wgpu::BindGroup {
        let (view, empty) = &self.index[g];
        let faces = match self.fresnel.get() {
            Some(f) if fresnel => &f[g],
            _ => &self.no_fresnel,
        };
        self.bind(
            0,
            &[
                run.params.as_entire_binding(),
                wgpu::BindingResource::TextureView(&view.view),
                wgpu::BindingResource::TextureView(&self.extinction.view),
                empty.as_entire_binding(),
                run.stats.as_entire_binding(),
                pyramid.as_entire_binding(),
                fates.as_entire_binding(),
                deps.as_entire_binding(),
                wgpu::BindingResource::TextureView(&faces.view),
                self.table.as_entire_binding(),
                front.as_entire_binding(),
                self.data.as_entire_binding(),
            ],
        )
    }

    /// Clear the tallies and what a wavefront group deposits on its own:
    /// the flux vectors (the fluence adds up over the groups), or the
    /// paper's keys and directions (the other channels' irradiance stays).
    fn begin_group(&self, run: &Run, fluence: bool) {
        let gpu = self.gpu;
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&run.stats, 0, None);
        if fluence {
            for b in &run.volume[6..12] {
                enc.clear_buffer(b, 0, None);
            }
        } else {
            enc.clear_buffer(&run.volume[0], 0, None);
            for b in &run.volume[6..9] {
                enc.clear_buffer(b, 0, None);
            }
        }
        gpu.submit([enc.finish()]);
    }

    /// The steps of one wavefront, scheduled by the device itself (the
    /// plan, see `simulate.wgsl`): a submission holds up to
    /// `MOST_STEPS_PER_SUBMISSION` steps and ends with one read-back of
    /// the plan's state. Where the plan halted the host makes room for the
    /// list (or the torn patches' pieces, then goes on after pass 0 of that
    /// step), or ends the wavefront: nothing left, or the step limit, where
    /// the patches left are tallied as trapped. The kernels run in the same
    /// order on the same data as one submission per step would, so the
    /// result is the same bit for bit.
    fn trace(
        &self,
        run: &Run,
        lists: &mut Lists,
        (params, stamp): (&mut SimParams, &mut u32),
        n0: usize,
        max_steps: usize,
        progress: Progress,
    ) -> Result<Traced, Error> {
        let gpu = self.gpu;
        params.n = n0 as u32;
        params.n_old = 0;
        params.stamp = *stamp;
        params.splits_base = lists.splits_base();
        params.pieces_base = lists.pieces_base();
        gpu.queue
            .write_buffer(&run.params, 0, bytemuck::bytes_of(params));
        let mut state = [0u32; PLAN_STATE];
        state[PL_MAX_STEPS] = max_steps.min(u32::MAX as usize) as u32;
        state[PL_CUR] = lists.cur as u32;
        state[PL_STAMP] = *stamp;
        let mut steps = FIRST_STEPS_PER_SUBMISSION;
        // Where a step the plan halted in its middle goes on.
        let mut resume: Option<Resume> = None;
        loop {
            state[PL_HALT] = HALT_NONE;
            state[PL_CAP] = lists.sets[0].cap as u32;
            state[PL_CAP + 1] = lists.sets[1].cap as u32;
            state[PL_SCRATCH] = lists.scratch_cap as u32;
            gpu.queue
                .write_buffer(&run.plan, 0, bytemuck::cast_slice(&state));
            let s0 = state[PL_STEPS];
            // No more steps than the limit leaves: a step the plan halts
            // costs little on a GPU but its dispatches' setup on lavapipe.
            let batch = steps.min(max_steps.saturating_sub(s0 as usize)).max(1);
            gpu.checked("light simulation steps", || {
                let mut enc = gpu.device.create_command_encoder(&Default::default());
                let mut cur = lists.cur;
                let mut rebuild = state[PL_REBUILD] != 0;
                match resume {
                    Some(Resume::Level(level)) => {
                        self.encode_levels(&mut enc, run, lists, cur, level);
                        self.encode_back(&mut enc, run, lists, cur);
                    }
                    Some(Resume::Pieces) => self.encode_back(&mut enc, run, lists, cur),
                    None => {}
                }
                for _ in 0..batch {
                    if rebuild {
                        cur = 1 - cur;
                    }
                    self.encode_front(&mut enc, run, lists, cur, rebuild);
                    if self.regions.is_some() {
                        self.encode_levels(&mut enc, run, lists, cur, 1);
                    }
                    self.encode_back(&mut enc, run, lists, cur);
                    rebuild = true;
                }
                gpu.submit([enc.finish()]);
            })?;
            let words = gpu.read::<u32>(&run.plan, PLAN_STATE)?;
            state.copy_from_slice(&words);
            lists.cur = state[PL_CUR] as usize;
            resume = None;
            let traced = Traced {
                steps: state[PL_STEPS] as usize,
                peak: state[PL_PEAK] as usize,
                left: 0,
            };
            progress(traced.steps, state[PL_TOTAL] as usize);
            match state[PL_HALT] {
                HALT_NONE => {
                    steps = (2 * batch).min(MOST_STEPS_PER_SUBMISSION);
                    // After a halt for room the lists may differ: the one
                    // the next walk writes (free now) is made as large as
                    // the live one, so that the next step does not halt.
                    let cur = lists.cur;
                    if lists.sets[1 - cur].cap < lists.sets[cur].cap {
                        self.fit(run, lists, lists.sets[cur].cap)?;
                    }
                }
                HALT_ROOM => {
                    self.fit(run, lists, state[PL_TOTAL] as usize)?;
                    // The lists take turns: where the other is still the
                    // smaller, it is grown after one step, when it is no
                    // longer read; else as many steps as ran may run
                    // before they must grow again.
                    let cur = lists.cur;
                    steps = if lists.sets[cur].cap < lists.sets[1 - cur].cap {
                        1
                    } else {
                        (traced.steps - s0 as usize).max(1)
                    };
                }
                HALT_PIECES => {
                    let (n, len) = (state[PL_TOTAL] as usize, state[PL_LEN] as usize);
                    self.grow_live(lists, n, len)?;
                    self.fit_scratch(run, lists, len)?;
                    resume = Some(Resume::Pieces);
                    steps = (traced.steps - s0 as usize).max(1);
                }
                HALT_FRONTIER => {
                    self.fit_scratch(run, lists, state[PL_FRONT] as usize)?;
                    resume = Some(Resume::Level(state[PL_LEVEL]));
                    steps = (traced.steps - s0 as usize).max(1);
                }
                HALT_DONE => {
                    *stamp = state[PL_STAMP];
                    return Ok(traced);
                }
                _ => {
                    self.trap_rest(run, lists, params, &mut state)?;
                    *stamp = state[PL_STAMP];
                    let left = state[PL_TOTAL] as usize;
                    return Ok(Traced { left, ..traced });
                }
            }
        }
    }

    /// At the step limit: the list the last step's grants asked for is
    /// written (and, with the paper's deposit, deposited, as the CPU does
    /// before it checks the limit), and its patches are tallied as trapped.
    fn trap_rest(
        &self,
        run: &Run,
        lists: &mut Lists,
        params: &mut SimParams,
        state: &mut [u32; PLAN_STATE],
    ) -> Result<(), Error> {
        let gpu = self.gpu;
        let rebuild = state[PL_REBUILD] != 0;
        let n = state[PL_TOTAL] as usize;
        params.n = n as u32;
        if rebuild {
            params.n_old = state[PL_LEN];
            lists.cur = 1 - lists.cur;
        }
        params.stamp = state[PL_STAMP];
        state[PL_STAMP] += 2;
        params.splits_base = lists.splits_base();
        params.pieces_base = lists.pieces_base();
        gpu.queue
            .write_buffer(&run.params, 0, bytemuck::bytes_of(params));
        gpu.checked("light simulation step", || {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_bind_group(0, &lists.medium_group, &[]);
                pass.set_bind_group(2, &run.volume_group, &[]);
                pass.set_bind_group(3, &run.levels[0][0].1, &[]);
                let cur = lists.cur;
                if rebuild {
                    pass.set_bind_group(1, &lists.patch_groups[1 - cur], &[]);
                    dispatch(&mut pass, self.kernel(Kernel::Rebuild), n);
                }
                pass.set_bind_group(1, &lists.patch_groups[cur], &[]);
                if params.fluence == 0 {
                    for k in PAPER_DEPOSIT {
                        dispatch(&mut pass, self.kernel(k), n);
                    }
                }
                dispatch(&mut pass, self.kernel(Kernel::CullRest), n);
            }
            gpu.submit([enc.finish()]);
        })?;
        Ok(())
    }

    /// One run of a plan kernel, then its parameter block copied into `P`.
    fn encode_plan(&self, enc: &mut wgpu::CommandEncoder, run: &Run, lists: &Lists, which: usize) {
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_bind_group(0, &lists.medium_group, &[]);
            pass.set_bind_group(1, &lists.patch_groups[lists.cur], &[]);
            pass.set_bind_group(2, &run.volume_group, &[]);
            pass.set_bind_group(3, &run.plan_group, &[]);
            pass.set_pipeline(&self.plans[which]);
            pass.dispatch_workgroups(1, 1, 1);
        }
        let size = std::mem::size_of::<SimParams>() as u64;
        enc.copy_buffer_to_buffer(&run.plan, PLAN_PARAMS_AT, &run.params, 0, size);
    }

    /// Dispatch `kernel` over the threads the plan put in `slot`.
    fn planned(&self, pass: &mut wgpu::ComputePass, run: &Run, k: Kernel, slot: usize) {
        pass.set_pipeline(self.kernel(k));
        pass.dispatch_workgroups_indirect(&run.plan, PLAN_ARGS_AT + slot as u64 * 12);
    }

    /// The reductions of `pyramid` (0 the counts', 1 the split flags', 2
    /// the pieces') whose sizes the plan put in the slots from `first`: as
    /// many levels as a pyramid over the scratch can have.
    fn planned_levels(
        &self,
        pass: &mut wgpu::ComputePass,
        run: &Run,
        lists: &Lists,
        pyramid: usize,
        first: usize,
    ) {
        let depth = pyramid_depth(lists.scratch_cap).min(MAX_LEVELS);
        for l in 1..depth {
            pass.set_bind_group(3, &run.levels[pyramid][l].1, &[]);
            self.planned(pass, run, Kernel::Reduce, first + l - 1);
        }
    }

    /// The first part of a step, in the CPU loop's order, after the plan:
    /// the walk that rebuilds the list the last step's grants asked for
    /// (into list `cur`, unless this is the wavefront's first step), the
    /// paper's deposit, and step 1 (propagate, with the fluence deposit).
    /// With sharp interfaces step 1 is `propagate_sharp`'s pass 0, followed
    /// by the pyramid of the torn patches' extra pieces.
    fn encode_front(
        &self,
        enc: &mut wgpu::CommandEncoder,
        run: &Run,
        lists: &Lists,
        cur: usize,
        rebuild: bool,
    ) {
        self.encode_plan(enc, run, lists, PLAN_STEP);
        let sharp = self.regions.is_some();
        let fluence = lists.dep_bytes == 0;
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_bind_group(0, &lists.medium_group, &[]);
        pass.set_bind_group(2, &run.volume_group, &[]);
        pass.set_bind_group(3, &run.levels[0][0].1, &[]);
        if rebuild {
            // The walk writes the live list from the previous one.
            pass.set_bind_group(1, &lists.patch_groups[1 - cur], &[]);
            self.planned(&mut pass, run, Kernel::Rebuild, A_REBUILD);
        }
        pass.set_bind_group(1, &lists.patch_groups[cur], &[]);
        if !fluence {
            for k in PAPER_DEPOSIT {
                self.planned(&mut pass, run, k, A_N);
            }
        }
        let step = if sharp {
            Kernel::PropagateSharp
        } else if fluence {
            Kernel::PropagateTube
        } else {
            Kernel::Propagate
        };
        if sharp {
            pass.set_bind_group(3, &run.passes[SHARP_PATCHES as usize].1, &[]);
        }
        self.planned(&mut pass, run, step, A_N);
        if sharp {
            // The pyramid of the torn patches' quarters (level 0 of their
            // trees' frontier: the counts' pyramid, free until `grant`).
            self.planned_levels(&mut pass, run, lists, 0, A_LEVELS_N);
        }
    }

    /// The torn patches' trees of quarters, level by level from `from`
    /// (each planned by `plan_level`: its frontier traced by
    /// `sharp_level`, whose counts `front_build` sums), then their numbers
    /// of pieces (`sharp_count`) and the pieces' pyramid over the list.
    fn encode_levels(
        &self,
        enc: &mut wgpu::CommandEncoder,
        run: &Run,
        lists: &Lists,
        cur: usize,
        from: u32,
    ) {
        for _ in from..=propagate::MAX_SPLIT_LEVEL {
            self.encode_plan(enc, run, lists, PLAN_LEVEL);
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_bind_group(0, &lists.medium_group, &[]);
            pass.set_bind_group(1, &lists.patch_groups[cur], &[]);
            pass.set_bind_group(2, &run.volume_group, &[]);
            pass.set_bind_group(3, &run.passes[SHARP_LEVEL as usize].1, &[]);
            self.planned(&mut pass, run, Kernel::PropagateSharp, A_FRONT);
            self.planned(&mut pass, run, Kernel::FrontBuild, A_BUILD);
        }
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_bind_group(0, &lists.medium_group, &[]);
        pass.set_bind_group(1, &lists.patch_groups[cur], &[]);
        pass.set_bind_group(2, &run.volume_group, &[]);
        pass.set_bind_group(3, &run.levels[0][0].1, &[]);
        self.planned(&mut pass, run, Kernel::SharpCount, A_COUNT);
        self.planned_levels(&mut pass, run, lists, 2, A_LEVELS_N);
    }

    /// The rest of a step over list `cur`: with sharp interfaces, the plan
    /// of the torn patches' pieces and the reflections, pass 1 (the
    /// reflections) and pass 2 (the pieces), which write them after the
    /// list; then `refine`: its tallies (`analyse`), the split grants (the
    /// split flags' pyramid, `grant`) and the counts' pyramid the next
    /// walk reads.
    fn encode_back(&self, enc: &mut wgpu::CommandEncoder, run: &Run, lists: &Lists, cur: usize) {
        let sharp = self.regions.is_some();
        if sharp {
            self.encode_plan(enc, run, lists, PLAN_PIECES);
        }
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_bind_group(0, &lists.medium_group, &[]);
        pass.set_bind_group(1, &lists.patch_groups[cur], &[]);
        pass.set_bind_group(2, &run.volume_group, &[]);
        pass.set_bind_group(3, &run.levels[0][0].1, &[]);
        if sharp {
            pass.set_bind_group(3, &run.passes[SHARP_REFLECTIONS as usize].1, &[]);
            self.planned(&mut pass, run, Kernel::PropagateSharp, A_PASS1);
            pass.set_bind_group(3, &run.passes[SHARP_PIECES as usize].1, &[]);
            self.planned(&mut pass, run, Kernel::PropagateSharp, A_PIECES);
            pass.set_bind_group(3, &run.levels[0][0].1, &[]);
        }
        self.planned(&mut pass, run, Kernel::Analyse, A_LEN);
        self.planned_levels(&mut pass, run, lists, 1, A_LEVELS_LEN);
        self.planned(&mut pass, run, Kernel::Grant, A_LEN);
        self.planned_levels(&mut pass, run, lists, 0, A_LEVELS_LEN);
    }

    /// Make the scratch hold `need` patches (or entries of a level of the
    /// torn patches' trees), what it holds carried over: the pyramids (each
    /// moved to its base over the new size), the fates and the frontier.
    fn fit_scratch(&self, run: &Run, lists: &mut Lists, need: usize) -> Result<(), Error> {
        if need <= lists.scratch_cap {
            return Ok(());
        }
        let old = lists.scratch_cap;
        let cap = need.max(2 * old).min(lists.most);
        if need > cap {
            return Err(too_large(
                "the light simulator's scratch (patches, or pieces of torn patches)",
                need as u64,
                cap as u64,
                "lower the resolution or use --backend cpu",
            )
            .into());
        }
        let gpu = self.gpu;
        let [pyramid, fates, deps, front] = self.scratch(cap, lists.dep_bytes, lists.sharp);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        let (from, to) = (pyramid_size(old) as u64 * 4, pyramid_size(cap) as u64 * 4);
        let pyramids = if lists.sharp { 3 } else { 2 };
        for r in 0..pyramids {
            enc.copy_buffer_to_buffer(&lists.pyramid, r * from, &pyramid, r * to, from);
        }
        enc.copy_buffer_to_buffer(&lists.fates, 0, &fates, 0, old as u64 * 4);
        if lists.sharp {
            let half = FRONT_BYTES / 2;
            for level in 0..2 {
                let (a, b) = (level * old as u64 * half, level * cap as u64 * half);
                enc.copy_buffer_to_buffer(&lists.front, a, &front, b, old as u64 * half);
            }
        }
        gpu.submit([enc.finish()]);
        lists.pyramid = pyramid;
        lists.fates = fates;
        lists.deps = deps;
        lists.front = front;
        lists.scratch_cap = cap;
        lists.medium_group = self.bind_medium(
            run,
            lists.channel,
            lists.fresnel,
            [&lists.pyramid, &lists.fates, &lists.deps, &lists.front],
        );
        Ok(())
    }

    /// List `which`, whose patches nothing reads any more, made again to
    /// hold `cap` (freed first, with the bind groups that hold it).
    fn remake_list(&self, lists: &mut Lists, which: usize, cap: usize) {
        lists.patch_groups.clear();
        lists.sets[which] = PatchSet::new(self.gpu, 0);
        lists.sets[which] = PatchSet::new(self.gpu, cap);
        lists.patch_groups = self.patch_groups(&lists.sets);
    }

    /// Make room in the live list, which holds `n` patches, for `len`
    /// (its patches copied into the larger list).
    fn grow_live(&self, lists: &mut Lists, n: usize, len: usize) -> Result<(), Error> {
        let gpu = self.gpu;
        let cur = lists.cur;
        if len > lists.sets[cur].cap {
            let cap = len.max(2 * lists.sets[cur].cap).min(lists.most);
            if len > cap {
                return Err(too_large(
                    "the wavefront with the pieces of torn patches (patches)",
                    len as u64,
                    cap as u64,
                    "lower the resolution or use --backend cpu",
                )
                .into());
            }
            lists.patch_groups.clear();
            let set = PatchSet::new(gpu, cap);
            let old = &lists.sets[cur];
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            let n = n as u64;
            enc.copy_buffer_to_buffer(&old.pos, 0, &set.pos, 0, n * POS_BYTES);
            enc.copy_buffer_to_buffer(&old.vel, 0, &set.vel, 0, n * VEL_BYTES);
            enc.copy_buffer_to_buffer(&old.aux, 0, &set.aux, 0, n * AUX_BYTES);
            gpu.submit([enc.finish()]);
            lists.sets[cur] = set;
            lists.patch_groups = self.patch_groups(&lists.sets);
        }
        Ok(())
    }

    /// Make room for the `total` patches the next walk writes: the list it
    /// writes, and the scratch (carrying the counts' pyramid over, which
    /// the walk still reads).
    fn fit(&self, run: &Run, lists: &mut Lists, total: usize) -> Result<(), Error> {
        let dst = 1 - lists.cur;
        if total > lists.sets[dst].cap {
            let cap = total.max(2 * lists.sets[dst].cap).min(lists.most);
            if total > cap {
                return Err(too_large(
                    "the wavefront (patches)",
                    total as u64,
                    cap as u64,
                    "lower max-patches",
                )
                .into());
            }
            // The walk overwrites the other list.
            self.remake_list(lists, dst, cap);
        }
        self.fit_scratch(run, lists, total)
    }

    /// Read back a wavefront group's tallies into `summary` and its share
    /// of the light volume: the flux vectors into `tally` (the fluence
    /// deposit), or the paper's directions into `directions`.
    fn end_group(
        &self,
        run: &Run,
        params: &SimParams,
        summary: &mut Summary,
        g: usize,
        tally: Option<&mut Counters>,
        directions: &mut Vec<Array4<f32>>,
    ) -> Result<(), Error> {
        let gpu = self.gpu;
        let grid = &self.medium.geometry;
        let s = gpu.read::<u32>(&run.stats, STATS_WORDS)?;
        let scale = params.scale as f64;
        let energy = |cat: usize, c: usize| {
            let w = 2 * (3 * cat + c);
            (s[w] as f64 + s[w + 1] as f64 * 4294967296.0) / scale
        };
        for c in 0..3 {
            summary.absorbed_power[c] += energy(0, c) - energy(6, c);
            summary.exited_power[c] += energy(1, c);
            summary.culled_power[c] += energy(2, c);
            summary.reflected_power[c] += energy(3, c);
            summary.trapped_power[c] += energy(4, c);
            summary.torn_power[c] += energy(5, c);
        }
        summary.torn += s[S_TORN] as usize;
        summary.reflections += s[S_REFLECTIONS] as usize;
        summary.exited += s[S_EXITED] as usize;
        summary.absorbed += s[S_ABSORBED] as usize;
        summary.faint += s[S_FAINT] as usize;
        summary.caustic += s[S_CAUSTIC] as usize;
        summary.held += s[S_HELD] as usize;
        match tally {
            Some(t) => {
                let cells = grid.voxel_count();
                for a in 0..3 {
                    let units = read_u64(gpu, &run.volume[6 + a], &run.volume[9 + a], cells)?;
                    let units: Vec<i64> = units.into_iter().map(|u| u as i64).collect();
                    t.add_flux_units(g, a, &units);
                }
            }
            None => directions.push(read_rgb(gpu, &run.volume[6..9], grid.dims)?),
        }
        Ok(())
    }

    /// The fluence deposit's light volume: the GPU's fluence counters
    /// added to `tally` (which holds the start spheres' chords and the
    /// flux vectors), converted as on the CPU.
    fn fluence_volume(&self, run: &Run, mut tally: Counters) -> Result<LightVolume, Error> {
        let cells = self.medium.geometry.voxel_count();
        for c in 0..3 {
            let units = read_u64(self.gpu, &run.volume[c], &run.volume[3 + c], cells)?;
            tally.add_fluence_units(c, &units);
        }
        Ok(tally.into_volume())
    }
}

/// A 64-bit counter per cell from its low and high words.
fn read_u64(
    gpu: &Gpu,
    lo: &wgpu::Buffer,
    hi: &wgpu::Buffer,
    cells: usize,
) -> Result<Vec<u64>, GpuError> {
    let (lo, hi) = (gpu.read::<u32>(lo, cells)?, gpu.read::<u32>(hi, cells)?);
    Ok(lo
        .into_iter()
        .zip(hi)
        .map(|(l, h)| l as u64 | (h as u64) << 32)
        .collect())
}

/// Three per-component buffers interleaved into `(nx, ny, nz, 3)`.
fn read_rgb(gpu: &Gpu, bufs: &[Buffer], dims: [usize; 3]) -> Result<Array4<f32>, GpuError> {
    let cells = dims[0] * dims[1] * dims[2];
    let mut out = Array4::zeros((dims[0], dims[1], dims[2], 3));
    let flat = out.as_slice_mut().expect("contiguous");
    for (c, b) in bufs.iter().enumerate() {
        let v = gpu.read::<f32>(b, cells)?;
        for (o, x) in flat.chunks_exact_mut(3).zip(v) {
            o[c] = x;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The composed source parses and validates as wgpu compiles it, and
    /// its parameter blocks have the Rust structs' offsets (no device
    /// needed).
    #[test]
    fn the_kernels_validate_and_their_layouts_match_rust() {
        let module = eikon_gpu::layout::validate(&source()).unwrap_or_else(|e| panic!("{e}"));
        eikon_gpu::layout::check::<SimParams>(&module).unwrap();
        eikon_gpu::layout::check::<PyramidLevel>(&module).unwrap();
        eikon_gpu::layout::check::<GridGpu>(&module).unwrap();
        // The plan's members where the host copies and dispatches from.
        let (offsets, span) = eikon_gpu::layout::offsets(&module, "Plan").unwrap();
        assert_eq!(offsets, [0, PLAN_PARAMS_AT, PLAN_ARGS_AT]);
        assert_eq!(span, PLAN_BYTES);
        for k in KERNELS {
            assert!(
                module.entry_points.iter().any(|e| e.name == k),
                "no entry point {k}"
            );
        }
    }

    #[test]
    fn pyramid_levels_tile_its_size() {
        let l = pyramid_levels(17);
        assert_eq!(l, vec![(0, 17), (17, 5), (22, 2), (24, 1)]);
        assert_eq!(pyramid_size(17), 25);
        assert_eq!(pyramid_levels(0), vec![(0, 1)]);
        for n in [0, 1, 4, 5, 17, 4096, 4097] {
            assert_eq!(pyramid_depth(n), pyramid_levels(n).len(), "{n}");
        }
    }
}
