//! # eikon-wavefront
//!
//! Light simulation by adaptive wavefront tracing
//! ([Ihrke07 secs 4.2 and 5.2]). Each light emits a wavefront of four-particle
//! patches where it meets the volume ([`light`]); then every step runs
//! the steps of the paper as a few calls in [`simulate_light`]:
//!
//! 1. [`propagate`](propagate::propagate): corners move with [Ihrke07 eqs 14-15]; the tube
//!    each patch sweeps is deposited into the light volume as track-length fluence and net
//!    flux ([`deposit`], beyond the paper: every ray family adds, through caustics too);
//!    flux is attenuated with [Ihrke07 eq 18] and by Fresnel transmission at interfaces
//!    (beyond the paper); with sharp interfaces and [`Options::reflections`] the reflected
//!    part goes on as a patch of its own once a patch has crossed a surface
//!    ([`propagate::reflection`]);
//! 2. [`refine`](refine::refine): tessellation analysis (eliminate, retain, tessellate)
//!    and the new patch list through a [`HistoPyramid`].
//!
//! With `--deposit paper` ([`DepositRule::Paper`]) the paper's own steps run instead of
//! the deposit in step 1: each patch's [`irradiance`](Patches::irradiance) ([Ihrke07 eq 17],
//! flux over area), patches culled where they flip at a caustic, and
//! [`PaperVolume::deposit`](deposit::paper::PaperVolume::deposit) keeping the highest-energy
//! ray per cell [Ihrke07 sec 5.2.2].
//!
//! [`photons`] is the brute-force baseline: photons with the same track-length deposit.
//!
//! Everything is deterministic: the same scene gives the same volumes
//! whatever the number of threads.

pub mod deposit;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod histopyramid;
pub mod light;
pub mod lightdir;
pub mod patch;
pub mod photons;
pub mod propagate;
pub mod refine;
pub mod staging;
pub mod volume;

pub use histopyramid::HistoPyramid;
pub use patch::Patches;
pub use volume::LightVolume;

use deposit::Counters;
use eikon_grid::interface::{probe_length, Interfaces};
use eikon_grid::{Integrator, Light, Medium, Progress, Scene};
use rayon::prelude::*;

/// How the wavefront becomes a light volume.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DepositRule {
    /// Track-length fluence and net flux of every patch, every step
    /// ([`deposit`]); light passes through caustics.
    #[default]
    Fluence,
    /// The paper's rule [Ihrke07 secs 5.2.2, 5.2.3]: the highest-energy ray per
    /// cell as a point value, patches culled at caustic flips
    /// ([`deposit::paper`]).
    Paper,
}

/// Size of the emitted patches at sharp interfaces, voxels (the default
/// of `--patch-size` there): the size of the deposit's sub-patches
/// ([`deposit::SUBPATCH_SIZE`]), so that every sub-patch of an emitted
/// patch follows a traced ray of its own rather than the bilinear
/// interpolation of rays a voxel apart. The wave a curved surface refracts
/// converges without being split, so its ray map is sampled only as finely
/// as it was emitted: against independent photons the glass sphere's light
/// read with a smaller error, for a little more time (docs/PERFORMANCE.md,
/// fourteenth session on issue 16).
pub const PATCH_SIZE: f64 = deposit::SUBPATCH_SIZE;

/// Size of the emitted patches with the smoothed index, voxels (the
/// default of `--patch-size` there): one voxel. The smoothed interface
/// bends the wave over a band of voxels, and its own bias (the sphere made
/// a voxel wider, grazing light under-reflected) is what the light reads
/// wrong there: the caustic under the [Ihrke07 fig 7] sphere carried the
/// same power against exact ray optics to four digits at either size, for
/// twice the time at half a voxel (docs/PERFORMANCE.md, fifteenth session
/// on issue 16).
pub const SMOOTHED_PATCH_SIZE: f64 = 1.0;

/// Patches whose irradiance has fallen below this fraction of what the
/// light would give at their place unobstructed are not split further
/// (with the fluence deposit; [`refine::Rules::dim`]).
pub const DIM_SPLIT: f64 = 0.05;

/// Patches carrying less than this fraction of what one voxel of the
/// light's unobstructed beam carries end (with the fluence deposit;
/// [`refine::Rules::faint`]), their power counted as trapped (still
/// travelling when no longer followed).
pub const FAINT: f64 = 1e-4;

/// Fixed-point units the whole power of a light deposits over one voxel
/// length: a piece of a chord is rounded to `2^-40` of that (fewer where
/// the counters could overflow otherwise: [`units_per_crossing`]).
pub const UNITS_PER_CROSSING: f64 = (1u64 << 40) as f64;

/// Fixed-point units per voxel crossing of the whole power (the power
/// bound of the counters) when no cell can be crossed by more than
/// `crossings` times that power in all: [`UNITS_PER_CROSSING`], or fewer
/// where a counter could otherwise overflow. Rounding each piece to the
/// nearest unit at most doubles what it adds (a piece under half a unit
/// adds nothing), so `2 crossings units` must stay within `2^62`: the
/// signed 64-bit flux-vector counters' range with a factor two to spare.
/// The counters hold integers, so overflow would wrap silently; with this
/// bound it cannot happen.
pub fn units_per_crossing(crossings: f64) -> f64 {
    let limit = 2f64.powi(62) / (2.0 * crossings.max(1.0));
    UNITS_PER_CROSSING.min(limit)
}

/// The most voxel crossings of the whole power any one cell can receive in
/// a simulation of at most `max_steps` steps of `step` voxels of optical
/// path: per step no more than all the power alive (never more than was
/// emitted) over one step's length, `step / n_min` voxels, plus the
/// chords from a light inside the volume to the sphere its wavefront
/// starts on.
pub(crate) fn crossings_bound(medium: &Medium, step: f64, max_steps: usize) -> f64 {
    let n_min = (medium.index_range().0 as f64).max(1e-6);
    step / n_min * max_steps as f64 + light::INNER_RADIUS_VOXELS + 1.0
}

/// An upper bound of the power `light` can bring into `grid`, per channel
/// the largest: a point or spot light's power, a directional light's
/// irradiance over the cross-section of the grid's bounding sphere. The
/// fixed-point scale of the deposit.
pub fn power_bound(light: &Light, grid: &eikon_grid::GridGeometry) -> f64 {
    let p = match light {
        Light::Directional { power, .. } => {
            *power * (std::f64::consts::PI * 0.25 * grid.diagonal() * grid.diagonal())
        }
        Light::Point { power, .. } | Light::Spot { power, .. } => *power,
    };
    p.max_element()
}

/// With sharp interfaces, a patch torn at a surface is split down to this
/// fraction of the smaller of the emitted and the split size
/// ([`propagate::Sharp::min_span`]).
pub const SHARP_MIN_SPAN: f64 = 0.0625;

/// [`propagate::Sharp::min_span`] for `opts` on `grid`, world units (both
/// backends).
pub(crate) fn sharp_min_span(grid: &eikon_grid::GridGeometry, opts: &Options) -> f64 {
    SHARP_MIN_SPAN * opts.split.min(opts.emitted_size(true)) * grid.voxel_size()
}

/// Settings of a simulation.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Equal-time step, in voxels of optical path.
    pub step: f64,
    /// Integrator for the corners (Euler or RK4; the adaptive scheme would
    /// break the common time of a wavefront).
    pub integrator: Integrator,
    /// Size of the emitted patches, in voxels; `None` takes the
    /// interfaces' default ([`Options::emitted_size`]).
    pub patch_size: Option<f64>,
    /// Tessellate a patch whose span exceeds this many voxels.
    pub split: f64,
    /// Eliminate a patch whose transmittance falls below this.
    pub threshold: f64,
    /// Most patches alive at once (splits beyond are held back).
    pub max_patches: usize,
    /// Most tessellations of one emitted patch; `None` picks
    /// [`default_depth`].
    pub max_depth: Option<u8>,
    /// Step limit per wavefront; `None` picks one from the volume size.
    pub max_steps: Option<usize>,
    /// How the wavefront becomes a light volume.
    pub deposit: DepositRule,
    /// Fresnel transmission at interfaces (beyond the paper, whose
    /// [Ihrke07 eq 18] has none). The reflected part leaves the beam and is
    /// counted as reflected, or goes on as patches of its own with sharp
    /// interfaces and [`Options::reflections`].
    pub fresnel: bool,
    /// Trace the Fresnel-reflected light as patches of its own (sharp
    /// interfaces; [`propagate::reflection`]): the default, since without
    /// it the light volumes read low wherever reflected light goes (inside
    /// a glass ball, by the light its back surface reflects). Off, the
    /// reflected part leaves the beam and is counted as reflected, as
    /// smoothed interfaces always do.
    pub reflections: bool,
    /// On the CPU, let a patch in uniform space (one index and one
    /// extinction, empty space included) take up to
    /// [`propagate::MAX_RUN`] steps at once ([`propagate::Run`]), its tube
    /// deposited in one pass (the default). Off, every patch steps one step
    /// at a time, as on the GPU: the two backends then deposit the same
    /// tubes, to compare them.
    pub runs: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            step: 0.5,
            integrator: Integrator::Rk4,
            patch_size: None,
            split: 1.0,
            threshold: 1e-4,
            max_patches: 8 << 20,
            max_depth: None,
            max_steps: None,
            deposit: DepositRule::Fluence,
            fresnel: true,
            reflections: true,
            runs: true,
        }
    }
}

/// A setting or a scene that cannot be simulated.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An option is out of range.
    #[error("{option}: {message}")]
    Option {
        /// The option's name.
        option: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The scene cannot be lit as given.
    #[error(transparent)]
    Scene(#[from] eikon_grid::Error),
    /// The GPU backend failed (no adapter, a limit, a validation error).
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] eikon_gpu::GpuError),
    /// A value of the light volume or of the energy account is not finite
    /// (an overflow: the light's power concentrated beyond what f32
    /// holds). Nothing is written; the caller names the light
    /// (`light[i].power`).
    #[error("{0}")]
    NotFinite(String),
    /// What was asked reads the medium's voxel index or extinction, which
    /// a medium of the surfaces alone does not hold
    /// ([`Medium::build_surfaces_within`]).
    #[error("{0} reads the voxel index and extinction, which a medium of the surfaces alone (Medium::build_surfaces_within) does not hold")]
    NeedsVoxelFields(&'static str),
}

impl Options {
    /// The emitted patch size, voxels: [`Options::patch_size`], else
    /// [`PATCH_SIZE`] at sharp interfaces (`sharp`) and
    /// [`SMOOTHED_PATCH_SIZE`] with the smoothed index.
    pub fn emitted_size(&self, sharp: bool) -> f64 {
        self.patch_size.unwrap_or(if sharp {
            PATCH_SIZE
        } else {
            SMOOTHED_PATCH_SIZE
        })
    }

    /// These options with the emitted patch size settled for the
    /// interfaces ([`Options::emitted_size`]): what a simulation runs with
    /// and what a run records.
    pub fn settled(&self, sharp: bool) -> Options {
        Options {
            patch_size: Some(self.emitted_size(sharp)),
            ..*self
        }
    }

    /// Check every setting.
    pub fn check(&self) -> Result<(), Error> {
        let bad = |option, message: String| Err(Error::Option { option, message });
        let within = |v: f64, (lo, hi): (f64, f64)| v.is_finite() && v >= lo && v <= hi;
        if !within(self.step, STEP_RANGE) {
            return bad(
                "step",
                format!(
                    "must lie in [{}, {}] voxels, got {}",
                    STEP_RANGE.0, STEP_RANGE.1, self.step
                ),
            );
        }
        if self.integrator == Integrator::DormandPrince {
            return bad(
                "integrator",
                "adaptive steps break the common time of a wavefront; use euler or rk4".into(),
            );
        }
        if let Some(size) = self.patch_size.filter(|&s| !within(s, PATCH_RANGE)) {
            return bad(
                "patch-size",
                format!(
                    "must lie in [{}, {}] voxels, got {size}",
                    PATCH_RANGE.0, PATCH_RANGE.1
                ),
            );
        }
        if !within(self.split, PATCH_RANGE) {
            return bad(
                "split",
                format!(
                    "must lie in [{}, {}] voxels, got {}",
                    PATCH_RANGE.0, PATCH_RANGE.1, self.split
                ),
            );
        }
        if !(self.threshold > 0.0 && self.threshold < 1.0) {
            return bad(
                "threshold",
                format!(
                    "transmittance threshold must lie in (0, 1), got {}",
                    self.threshold
                ),
            );
        }
        if self.max_patches < 16 {
            return bad(
                "max-patches",
                format!("must be at least 16, got {}", self.max_patches),
            );
        }
        Ok(())
    }
}

/// What happened to one light's wavefront(s).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Summary {
    /// Steps of time the wavefront came (the longest wavefront's, with
    /// dispersion): its farthest patch's optical path over the step.
    pub steps: usize,
    /// Most patches alive at once.
    pub peak_patches: usize,
    /// Patches emitted.
    pub emitted: usize,
    /// Patches that left the volume.
    pub exited: usize,
    /// Patches eliminated by the transmittance threshold.
    pub absorbed: usize,
    /// Patches ended as too faint to follow, still travelling (with the
    /// fluence deposit; [`refine::Rules::faint`]).
    pub faint: usize,
    /// Patches eliminated at a caustic (the paper's deposit only).
    pub caustic: usize,
    /// Patches still alive at the step limit.
    pub step_limit: usize,
    /// Splits held back by the patch limit.
    pub held: usize,
    /// RGB power that entered the volume, W.
    pub entered: [f64; 3],
    /// RGB power taken out of the beams inside the volume (absorbed or
    /// scattered away), W.
    pub absorbed_power: [f64; 3],
    /// RGB power carried out of the volume, W.
    pub exited_power: [f64; 3],
    /// RGB power reflected at interfaces (Fresnel) and not traced, W.
    pub reflected_power: [f64; 3],
    /// Reflected patches traced on from a surface
    /// ([`propagate::reflection`]).
    pub reflections: usize,
    /// RGB power dropped with eliminated patches (transmittance threshold,
    /// caustics), W.
    pub culled_power: [f64; 3],
    /// RGB power still travelling when the simulation stopped following
    /// it, W: patches alive at the step limit, and patches split and
    /// dimmed until too faint to follow ([`FAINT`]). Light held by total
    /// internal reflection ends here (in clear glass mostly as faint
    /// patches: it splits without dimming), as do paths longer than the
    /// step limit.
    pub trapped_power: [f64; 3],
    /// Thin tubes (what a patch piece still torn at the smallest split goes
    /// on as) torn again at a sharp interface, and dropped
    /// ([`propagate::Sharp`]).
    pub torn: usize,
    /// RGB power they carried, W.
    pub torn_power: [f64; 3],
}

impl Summary {
    /// `entered - (absorbed + exited + reflected + culled + trapped + torn)`
    /// relative to `entered`, the largest over the channels that carry
    /// power.
    pub fn energy_imbalance(&self) -> f64 {
        (0..3)
            .filter(|&c| self.entered[c] > 0.0)
            .map(|c| {
                let out = self.absorbed_power[c]
                    + self.exited_power[c]
                    + self.reflected_power[c]
                    + self.culled_power[c]
                    + self.trapped_power[c]
                    + self.torn_power[c];
                (self.entered[c] - out).abs() / self.entered[c]
            })
            .fold(0.0, f64::max)
    }

    /// The trapped power's fraction of the entered power, the largest over
    /// the channels that carry power (0 when none entered).
    pub fn trapped_fraction(&self) -> f64 {
        (0..3)
            .filter(|&c| self.entered[c] > 0.0)
            .map(|c| self.trapped_power[c] / self.entered[c])
            .fold(0.0, f64::max)
    }

    /// An error unless every power of the account is finite.
    pub fn check_finite(&self) -> Result<(), Error> {
        for (name, v) in [
            ("entered", self.entered),
            ("absorbed", self.absorbed_power),
            ("exited", self.exited_power),
            ("reflected", self.reflected_power),
            ("culled", self.culled_power),
            ("trapped", self.trapped_power),
            ("torn", self.torn_power),
        ] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(Error::NotFinite(format!(
                    "the {name} power {v:?} W is not finite: the light's power overflows"
                )));
            }
        }
        Ok(())
    }
}

/// An error unless every value of `volume` is finite (see
/// [`Error::NotFinite`]): the first cell that is not, and where.
pub fn check_finite(volume: &LightVolume, summary: &Summary) -> Result<(), Error> {
    summary.check_finite()?;
    let arrays = std::iter::once(("fluence", &volume.fluence))
        .chain(volume.flux.iter().map(|f| ("flux vector", f)));
    for (name, a) in arrays {
        if let Some(((i, j, k, c), x)) = a.indexed_iter().find(|(_, x)| !x.is_finite()) {
            return Err(Error::NotFinite(format!(
                "the {name} of cell ({i}, {j}, {k}), component {c}, would be {x}: the light's power concentrated there overflows 32-bit floats (at most {:e}); lower the power",
                f32::MAX
            )));
        }
    }
    Ok(())
}

/// Default tessellation limit. A spherical wave's patches grow from about
/// a voxel to the volume's diagonal, and may halve that often. A plane
/// wave's patches only grow where optics spreads them, and a patch torn
/// across a discontinuity of the ray map (straddling an object's
/// silhouette, part of it skimming inside the smoothed interface) stretches
/// without bound: four levels (256 pieces of an emitted patch) leave room
/// for a diverging lens without letting a tear multiply unchecked. `opts`
/// as a simulation settles them ([`Options::settled`]; unsettled, the
/// patch size of sharp interfaces).
pub fn default_depth(light: &Light, grid: &eikon_grid::GridGeometry, opts: &Options) -> u8 {
    match light {
        Light::Directional { .. } => 4,
        _ => {
            let ratio =
                grid.diagonal() / (opts.split.min(opts.emitted_size(true)) * grid.voxel_size());
            (ratio.log2().ceil().max(0.0) as u8).saturating_add(1)
        }
    }
}

fn add(acc: &mut [f64; 3], x: &[f64; 3]) {
    (0..3).for_each(|c| acc[c] += x[c]);
}

/// Reject scenes that cannot be lit: no lights, or a point or spot light
/// inside matter so opaque that its light dies within a voxel.
pub fn check_scene(scene: &Scene, medium: &Medium, opts: &Options) -> Result<(), Error> {
    let opts = &opts.settled(scene.grid.interfaces == eikon_grid::Interfaces::Sharp);
    if scene.lights.is_empty() {
        return Err(scene
            .error_at(
                "light",
                "the scene has no [[light]]: there is nothing to simulate",
            )
            .into());
    }
    let h = medium.geometry.voxel_size();
    let g = &medium.geometry;
    // A medium of the surfaces alone has its regions' extinction only.
    let regions = (!medium.has_voxel_fields()).then(|| eikon_grid::Regions::new(scene));
    for (i, l) in scene.lights.iter().enumerate() {
        // Bounded work: a light far away, or patches tiny against the
        // volume, would make emission alone unbounded.
        if let Light::Point { position, .. } | Light::Spot { position, .. } = l {
            let far = position.distance(0.5 * (g.min + g.max));
            if far > MAX_LIGHT_DISTANCE * g.diagonal() {
                return Err(scene
                    .error_at(
                        &format!("light[{i}].position"),
                        format!(
                            "{far:e} from the volume's centre, more than {MAX_LIGHT_DISTANCE:e} of its diagonals: use a directional light"
                        ),
                    )
                    .into());
            }
        }
        let size = opts.emitted_size(true);
        let n = light::candidates(l, g, size * h);
        if n > (EMIT_PER_PATCH_LIMIT * opts.max_patches) as f64 {
            return Err(scene
                .error_at(
                    &format!("light[{i}]"),
                    format!(
                        "emitting it would take {n:.3e} patches of {size} voxel, more than {EMIT_PER_PATCH_LIMIT} x --max-patches ({}): raise --patch-size or --max-patches, or lower the resolution",
                        opts.max_patches
                    ),
                )
                .into());
        }
        let position = match l {
            Light::Point { position, .. } | Light::Spot { position, .. } => *position,
            Light::Directional { .. } => continue,
        };
        if !medium.geometry.contains(position) {
            continue;
        }
        let ext = extinction_at(medium, regions.as_ref(), position);
        if (0..3).all(|c| (-ext[c] * h).exp() < opts.threshold) {
            return Err(scene
                .error_at(
                    &format!("light[{i}].position"),
                    format!(
                        "the light sits in opaque matter (extinction {ext} per world unit): its light would not get one voxel away"
                    ),
                )
                .into());
        }
    }
    Ok(())
}

/// The extinction at `p`: the medium's voxels where it holds them, else
/// (a medium of the surfaces alone, [`Medium::has_voxel_fields`]) the
/// material of the region of `regions` there.
fn extinction_at(
    medium: &Medium,
    regions: Option<&eikon_grid::Regions>,
    p: glam::DVec3,
) -> glam::DVec3 {
    match regions {
        Some(r) if !medium.has_voxel_fields() => r.material(r.at(p)).extinction_at(p),
        _ => medium.sample_rgb(&medium.extinction, p),
    }
}

/// Farthest a point or spot light may be from the volume's centre, in
/// diagonals of the volume: beyond, its light is a plane wave to within
/// the grid's resolution, and its cube-sphere would be emitted in vain.
pub const MAX_LIGHT_DISTANCE: f64 = 1e4;

/// Emission considers at most this many patches per `max_patches`.
pub const EMIT_PER_PATCH_LIMIT: usize = 4;

/// The range of `--step`, voxels: below, a step budget tied to the volume
/// is no longer a bound on time.
pub const STEP_RANGE: (f64, f64) = (1.0 / 64.0, 4.0);

/// The range of `--patch-size` and `--split`, voxels.
pub const PATCH_RANGE: (f64, f64) = (1.0 / 16.0, 64.0);

/// What both backends derive from the options before stepping.
pub(crate) struct Plan {
    /// Tessellation analysis settings.
    pub rules: refine::Rules,
    /// Equal-time step, world units of optical path.
    pub dt: f64,
    /// Step limit per wavefront.
    pub max_steps: usize,
}

impl Plan {
    /// The plan for `light` in `medium` under `opts`.
    pub fn new(light: &Light, medium: &Medium, opts: &Options) -> Plan {
        let grid = &medium.geometry;
        let h = grid.voxel_size();
        let dt = opts.step * h;
        let n_max = medium.index_range().1 as f64;
        Plan {
            rules: refine::Rules {
                split_span: opts.split * h,
                threshold: opts.threshold,
                max_patches: opts.max_patches,
                max_depth: opts.max_depth.unwrap_or_else(|| {
                    if opts.deposit == DepositRule::Paper {
                        default_depth(light, grid, opts)
                    } else {
                        fluence_depth(light, grid, opts)
                    }
                }),
                cull_caustics: opts.deposit == DepositRule::Paper,
                dim: if opts.deposit == DepositRule::Paper {
                    0.0
                } else {
                    DIM_SPLIT
                },
                incident: refine::Incident::new(light, [1.0; 3]),
                faint: if opts.deposit == DepositRule::Paper {
                    0.0
                } else {
                    FAINT * h * h
                },
                corner_rays: deposit::corner_ray_span(h),
            },
            dt,
            max_steps: opts
                .max_steps
                .unwrap_or((16.0 * grid.diagonal() * n_max / dt).ceil() as usize),
        }
    }
}

/// The straight runs through uniform space under `opts`, within
/// `max_steps` ([`propagate::Run`]): none with the paper's deposit, which
/// samples the patches after every step, or without [`Options::runs`].
pub(crate) fn plan_run(rules: &refine::Rules, opts: &Options, max_steps: usize) -> propagate::Run {
    if opts.deposit == DepositRule::Paper || !opts.runs {
        return propagate::Run::NONE;
    }
    propagate::Run {
        max_steps: propagate::MAX_RUN,
        rules: Some(*rules),
        until: max_steps,
    }
}

/// Steps a wavefront from `light` takes to cross `medium` along straight
/// lines at its lowest index: where the light enters to the farthest point
/// it reaches. Refraction, trapped light and the step limit make the real
/// count differ; the command line uses it for an estimate of the time left.
pub fn crossing_steps(light: &Light, medium: &Medium, opts: &Options) -> usize {
    let g = &medium.geometry;
    let size = g.max - g.min;
    let distance = match light {
        // The wave starts where it enters the box; the longest chord of
        // the box along the beam ends it.
        Light::Directional { direction, .. } => {
            let d = direction.normalize_or_zero().abs();
            (0..3)
                .filter(|&i| d[i] > 0.0)
                .map(|i| size[i] / d[i])
                .fold(f64::INFINITY, f64::min)
        }
        // From the nearest point of the box to its farthest corner.
        Light::Point { position, .. } | Light::Spot { position, .. } => {
            let p = *position;
            let near = p.clamp(g.min, g.max).distance(p);
            let far = (p - g.min).abs().max((p - g.max).abs()).length();
            far - near
        }
    };
    // The equal-time step advances dt / n in space [Ihrke07 eqs 14-15].
    let n = (medium.index_range().0 as f64).max(1e-6);
    let dt = opts.step * g.voxel_size();
    (distance * n / dt).ceil().clamp(1.0, 1e12) as usize
}

/// Wavefront `g` of `groups`: the colour channels it carries (a mask) and,
/// with dispersion, the one channel it is traced for.
pub(crate) fn group(g: usize, groups: usize) -> ([f64; 3], Option<usize>) {
    if groups == 1 {
        ([1.0; 3], None)
    } else {
        let mut m = [0.0; 3];
        m[g] = 1.0;
        (m, Some(g))
    }
}

impl Summary {
    /// Count the patches (and their flux) that left the list in a refine.
    fn add_ended(&mut self, ended: &refine::Ended) {
        self.exited += ended.exited;
        self.absorbed += ended.absorbed;
        self.faint += ended.faint;
        self.caustic += ended.caustic;
        add(&mut self.exited_power, &ended.exited_flux);
        add(&mut self.culled_power, &ended.culled_flux);
        add(&mut self.trapped_power, &ended.faint_flux);
    }
}

/// The wavefront of `light` for colour `mask` as it enters the volume, on
/// either backend: emitted ([`light::emit`]), less what the medium absorbs
/// around a light inside it, and tessellated until no patch exceeds the
/// split size. Counts the entered, absorbed and ended power into `summary`.
/// With a `tally` (the track-length deposit), light inside the volume also
/// deposits the one-voxel sphere it starts on: straight chords from the
/// light to each patch (wavefront group `group`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn start_wavefront<F: eikon_grid::IndexField + ?Sized>(
    light: &Light,
    medium: &Medium,
    field: &F,
    opts: &Options,
    rules: &refine::Rules,
    (mask, group): ([f64; 3], Option<usize>),
    (p, next, scratch): (&mut Patches, &mut Patches, &mut refine::Scratch),
    tally: Option<&Counters>,
    summary: &mut Summary,
    hold: Option<refine::Hold>,
    regions: Option<&eikon_grid::Regions>,
) {
    let grid = &medium.geometry;
    let h = grid.voxel_size();
    p.clear();
    let size = opts.emitted_size(regions.is_some());
    let entered = light::emit(light, grid, field, size * h, mask, p);
    add(&mut summary.entered, &entered);
    // A light inside the volume emits from a sphere one voxel across
    // (a patch needs an area): what the medium absorbs within it,
    // [Ihrke07 eq 18] over that radius at the light's extinction, never reaches
    // it.
    if let Light::Point { position, .. } | Light::Spot { position, .. } = light {
        if grid.contains(*position) {
            let sigma = extinction_at(medium, regions, *position);
            let depth = sigma * light::INNER_RADIUS_VOXELS * h;
            let kept = (-depth).exp();
            if let Some(t) = tally {
                let at = [*position; 4];
                (0..p.len()).into_par_iter().for_each(|i| {
                    deposit::tube(t, &at, &p.positions(i), &p.flux[i], depth, group);
                });
            }
            for f in p.flux.iter_mut() {
                for c in 0..3 {
                    summary.absorbed_power[c] += f[c] * (1.0 - kept[c]);
                    f[c] *= kept[c];
                }
            }
        }
    }
    summary.emitted += p.len();
    // Patches that start far from a point light are larger than the
    // split size: tessellate them before the first step. With the fluence
    // deposit the tessellation budget counts from here (see
    // [`fluence_depth`]).
    let fluence = !rules.cull_caustics;
    let start_rules = refine::Rules {
        max_depth: if fluence { 16 } else { rules.max_depth },
        ..*rules
    };
    for _ in 0..16 {
        let before = p.len();
        let ended = refine::refine(
            p,
            next,
            scratch,
            field,
            grid,
            &start_rules,
            &mut summary.held,
            hold,
        );
        summary.add_ended(&ended);
        if p.len() == before {
            break;
        }
    }
    if fluence {
        p.depth.iter_mut().for_each(|d| *d = 0);
    }
}

/// Tessellation limit with the fluence deposit, counted from the wavefront
/// as it enters the volume (patches about a voxel across): four levels,
/// as for a plane wave ([`default_depth`]), plus what a spherical wave
/// needs to grow from the nearest point of the volume to the farthest (from
/// the one-voxel sphere it starts on when the light is inside). Counted
/// from emission instead, a light far outside spends its levels on
/// reaching the volume, and one inside on nothing: the budget then either
/// starves or lets light fanned out behind a caustic split without end
/// (a spot through a superquadric grew past a million patches). `opts` as
/// a simulation settles them ([`Options::settled`]; unsettled, the patch
/// size of sharp interfaces).
pub fn fluence_depth(light: &Light, grid: &eikon_grid::GridGeometry, opts: &Options) -> u8 {
    let position = match light {
        Light::Directional { .. } => return 4,
        Light::Point { position, .. } | Light::Spot { position, .. } => *position,
    };
    let h = grid.voxel_size();
    let near = (position.clamp(grid.min, grid.max) - position)
        .length()
        .max(light::INNER_RADIUS_VOXELS * h);
    let far = (0..8)
        .map(|i| {
            let c = glam::DVec3::new(
                if i & 1 == 0 { grid.min.x } else { grid.max.x },
                if i & 2 == 0 { grid.min.y } else { grid.max.y },
                if i & 4 == 0 { grid.min.z } else { grid.max.z },
            );
            (c - position).length()
        })
        .fold(0.0, f64::max);
    let grow = (far / near * opts.emitted_size(true) / opts.split)
        .log2()
        .ceil()
        .max(0.0);
    4 + grow.min(12.0) as u8
}

/// Simulate one light: its wavefront (or, with dispersion, one wavefront
/// per colour channel, each through its own index field) from emission to
/// the last patch. Returns the light volume and the summary. `progress`
/// hears `(step, live patches)` of the wavefront running.
pub fn simulate_light(
    light: &Light,
    medium: &Medium,
    opts: &Options,
    progress: Progress,
) -> Result<(LightVolume, Summary), Error> {
    simulate_light_in(light, medium, None, opts, progress)
}

/// [`simulate_light`] with sharp interfaces when `regions` are given
/// (`[grid] interfaces = "sharp"`, [`propagate::Sharp`]): corners cross
/// the scene's exact surfaces, each region's own index between them.
pub fn simulate_light_in(
    light: &Light,
    medium: &Medium,
    regions: Option<&eikon_grid::Regions>,
    opts: &Options,
    progress: Progress,
) -> Result<(LightVolume, Summary), Error> {
    opts.check()?;
    let opts = &opts.settled(regions.is_some());
    let grid = &medium.geometry;
    let groups = medium.channels();
    let paper = opts.deposit == DepositRule::Paper;
    if !medium.has_voxel_fields() {
        if regions.is_none() {
            return Err(Error::NeedsVoxelFields("the smoothed index"));
        }
        if paper {
            return Err(Error::NeedsVoxelFields("the paper's deposit"));
        }
    }
    let mut paper_volume = paper.then(|| deposit::paper::PaperVolume::new(grid, groups));
    let Plan {
        mut rules,
        dt,
        max_steps,
    } = Plan::new(light, medium, opts);
    let tally = (!paper).then(|| {
        Counters::new(
            grid,
            groups,
            [power_bound(light, grid); 3],
            units_per_crossing(crossings_bound(medium, opts.step, max_steps)),
        )
    });
    // The smoothed interfaces' sides, for Fresnel (sharp interfaces know
    // both indices at the surface).
    let interfaces =
        (opts.fresnel && regions.is_none()).then(|| Interfaces::new(medium, probe_length(medium)));
    let sharp = regions.map(|regions| propagate::Sharp {
        regions,
        min_span: sharp_min_span(grid, opts),
        fresnel: opts.fresnel,
        reflections: opts.reflections,
    });
    let straddles = |x: &[glam::DVec3; 4]| {
        regions.is_some_and(|r| {
            let at = r.at(x[0]);
            x[1..].iter().any(|&p| r.at(p) != at)
        })
    };
    let hold: Option<refine::Hold> = regions.is_some().then_some(&straddles);
    let mut summary = Summary::default();
    let (mut p, mut next) = (Patches::default(), Patches::default());
    let mut scratch = refine::Scratch::default();
    let mut losses = Vec::new();
    for g in 0..groups {
        let (mask, group) = group(g, groups);
        rules.incident = refine::Incident::new(light, mask);
        // The voxel index, which sharp interfaces do not read.
        let field = (regions.is_none() || paper).then(|| propagate::Bounded::new(medium, g));
        let exact = regions.map(|regions| propagate::RegionIndex {
            regions,
            channel: g,
        });
        // What emission and new corners read the index from.
        let shell: &dyn eikon_grid::IndexField = match (&exact, &field) {
            (Some(e), _) => e,
            (None, Some(f)) => f,
            (None, None) => unreachable!("the smoothed index has its field"),
        };
        // Empty space for the smoothed index's runs and the paper's deposit
        // (with sharp interfaces runs go by the regions themselves,
        // `propagate::Run`, and none is needed).
        let empty = match field {
            Some(_) => eikon_grid::EmptySpace::new(medium, g),
            None => eikon_grid::EmptySpace::unknown(grid),
        };
        start_wavefront(
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
            regions,
        );
        if let Some(v) = paper_volume.as_mut() {
            v.deposit(&p, medium, &empty, group);
        }
        let step_of = propagate::Step {
            medium,
            field: field.as_ref(),
            empty: &empty,
            integrator: opts.integrator,
            dt,
            interfaces: interfaces.as_ref(),
            channel: g,
            tally: tally.as_ref(),
            group,
            sharp: sharp.as_ref(),
            run: plan_run(&rules, opts, max_steps),
        };
        let (mut step, mut reached) = (0, 0);
        while !p.is_empty() && step < max_steps {
            step += 1;
            propagate::propagate(&mut p, &step_of, &mut losses);
            // Patches that ran through uniform space are ahead of the
            // common time: the wavefront has come as far as the farthest.
            let ahead = p.corner[0].iter().map(|c| c.opl).fold(0.0, f64::max);
            reached = reached.max(step).max((ahead / dt).round() as usize);
            for l in &losses {
                add(&mut summary.absorbed_power, &l.absorbed);
                add(&mut summary.reflected_power, &l.reflected);
                add(&mut summary.torn_power, &l.torn);
                summary.torn += l.torn_pieces;
                summary.reflections += l.reflections;
            }
            let ended = refine::refine(
                &mut p,
                &mut next,
                &mut scratch,
                shell,
                grid,
                &rules,
                &mut summary.held,
                hold,
            );
            summary.add_ended(&ended);
            if let Some(v) = paper_volume.as_mut() {
                v.deposit(&p, medium, &empty, group);
            }
            summary.peak_patches = summary.peak_patches.max(p.len());
            progress(reached, p.len());
        }
        summary.steps = summary.steps.max(reached);
        summary.step_limit += p.len();
        for f in &p.flux {
            add(&mut summary.trapped_power, f);
        }
    }
    // The wavefront's lists keep their peak capacity: gone before the
    // volume's arrays are made beside the counters.
    drop((p, next, scratch, losses));
    let volume = match (tally, paper_volume) {
        (Some(t), _) => t.into_volume(),
        (None, Some(v)) => v.into_volume(),
        (None, None) => unreachable!("one of the two deposits runs"),
    };
    check_finite(&volume, &summary)?;
    Ok((volume, summary))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The emitted patch size: the interfaces' default unless given, and
    /// settled options keep the size they were settled with.
    #[test]
    fn the_emitted_size_is_the_interfaces_default_unless_given() {
        let o = Options::default();
        assert_eq!(o.emitted_size(true), 0.5);
        assert_eq!(o.emitted_size(false), 1.0);
        let given = Options {
            patch_size: Some(0.75),
            ..o
        };
        assert_eq!(given.emitted_size(true), 0.75);
        assert_eq!(given.emitted_size(false), 0.75);
        for sharp in [true, false] {
            let s = o.settled(sharp);
            assert_eq!(s.patch_size, Some(o.emitted_size(sharp)));
            assert_eq!(s.emitted_size(!sharp), o.emitted_size(sharp));
        }
        let bad = Options {
            patch_size: Some(f64::NAN),
            ..o
        };
        assert!(matches!(
            bad.check(),
            Err(Error::Option {
                option: "patch-size",
                ..
            })
        ));
    }
}
