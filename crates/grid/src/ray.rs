//! The ray equation of geometric optics, `d/ds (n dx/ds) = grad n`
//! [Ihrke07 eq 8], in the two first-order forms of Ihrke et al. 2007:
//!
//! * **equal distance** [Ihrke07 eqs 9-10]: `dx/ds = v / n`, `dv/ds = grad n`,
//!   where `s` is arc length, so every step covers the same distance. Used for
//!   eye rays.
//! * **equal time** [Ihrke07 eqs 14-15]: `dx/dt = v / n^2`,
//!   `dv/dt = grad n / n`, where `dt = n ds` is optical path, so all particles
//!   launched together stay on one wavefront. Used for light.
//!
//! In both, `v = grad S` is the gradient of the eikonal, of length `n`.
//! The state also carries the optical path length `L = int n ds`
//! (`dL/ds = n`; in the equal-time form `dL/dt = 1`), integrated by the
//! same scheme.
//!
//! Integrators: forward Euler ([Ihrke07 eqs 11-12] and their equal-time
//! analogue), classical RK4, and adaptive Dormand-Prince 5(4). Total internal
//! reflection needs no special case: the ray turns inside the smoothed
//! interface because `v` keeps integrating `grad n`.

use crate::geometry::GridGeometry;
use eikon_shader::{Consts, Module};
use glam::DVec3;

/// A refractive-index field that can be sampled anywhere.
pub trait IndexField: Sync {
    /// Index `n` and its gradient (per world unit) at world point `p`.
    fn sample(&self, p: DVec3) -> (f64, DVec3);
}

/// Which parameterization of the ray equation to integrate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Form {
    /// [Ihrke07 eqs 9-10]: the step is a fixed distance (world units).
    EqualDistance,
    /// [Ihrke07 eqs 14-15]: the step is a fixed optical path (world units times
    /// n).
    EqualTime,
}

/// Numerical integration scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Integrator {
    /// Forward Euler, first order [Ihrke07 eqs 11-12].
    Euler,
    /// Classical Runge-Kutta, fourth order.
    Rk4,
    /// Dormand-Prince 5(4) with step-size control; the fixed step becomes
    /// the largest step it may take.
    DormandPrince,
}

fn ray_declarations() -> String {
    Consts::new()
        .u32("FORM_EQUAL_DISTANCE", Form::EqualDistance as u32)
        .u32("FORM_EQUAL_TIME", Form::EqualTime as u32)
        .u32("INTEGRATOR_EULER", Integrator::Euler as u32)
        .u32("INTEGRATOR_RK4", Integrator::Rk4 as u32)
        .wgsl()
        .to_string()
}

/// The WGSL of the ray equation: its right-hand side in both forms, the
/// Euler and RK4 increments and the step on the eikonal shell, over the
/// index field a kernel provides (the hook `index_field`). Dormand-Prince
/// has no GPU form: kernels take RK4 for it.
pub static WGSL: Module = Module {
    name: "ray",
    requires: &[],
    declarations: ray_declarations,
    text: include_str!("ray.wgsl"),
};

/// Position, eikonal gradient `v` (|v| = n) and optical path so far.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayState {
    /// World position.
    pub x: DVec3,
    /// `v = n dx/ds`.
    pub v: DVec3,
    /// Optical path length integrated so far.
    pub opl: f64,
}

impl RayState {
    /// A ray at `x` heading along unit `dir` in a medium of index `n`.
    pub fn new(x: DVec3, dir: DVec3, n: f64) -> Self {
        Self {
            x,
            v: dir * n,
            opl: 0.0,
        }
    }

    /// Unit direction of travel.
    pub fn direction(&self) -> DVec3 {
        self.v.normalize()
    }
}

/// Derivative of the state, the right-hand side of [Ihrke07 eqs 9-10 or 14-15].
#[derive(Clone, Copy)]
struct Deriv {
    x: DVec3,
    v: DVec3,
    opl: f64,
}

#[inline(always)]
fn deriv<F: IndexField + ?Sized>(f: &F, form: Form, x: DVec3, v: DVec3) -> Deriv {
    let (n, g) = f.sample(x);
    rhs(form, n, g, v)
}

/// The right-hand side from an index sample `(n, g)` already taken.
#[inline(always)]
fn rhs(form: Form, n: f64, g: DVec3, v: DVec3) -> Deriv {
    let inv = 1.0 / n;
    match form {
        // [Ihrke07 eqs 9, 10]; dL/ds = n by definition of optical path.
        Form::EqualDistance => Deriv {
            x: v * inv,
            v: g,
            opl: n,
        },
        // [Ihrke07 eqs 14, 15]; t is optical path itself ([Ihrke07 eq 24] in
        // the appendix: ds/dt = 1/n).
        Form::EqualTime => Deriv {
            x: v * (inv * inv),
            v: g * inv,
            opl: 1.0,
        },
    }
}

impl Deriv {
    const ZERO: Deriv = Deriv {
        x: DVec3::ZERO,
        v: DVec3::ZERO,
        opl: 0.0,
    };
}

#[inline(always)]
fn apply(s: &RayState, d: &Deriv, h: f64) -> RayState {
    RayState {
        x: s.x + d.x * h,
        v: s.v + d.v * h,
        opl: s.opl + d.opl * h,
    }
}

/// One forward-Euler step of size `h` ([Ihrke07 eqs 11-12] in the
/// equal-distance form). Always inlined: since `deriv` was split in two the
/// compiler kept it out of line, which cost a call per step (+15% instructions
/// per Euler step, docs/PERFORMANCE.md, "Ray steps per second").
#[inline(always)]
pub fn step_euler<F: IndexField + ?Sized>(f: &F, form: Form, s: &mut RayState, h: f64) {
    let k = deriv(f, form, s.x, s.v);
    *s = apply(s, &k, h);
}

/// One forward-Euler step of size `h` in the equal-distance form
/// [Ihrke07 eqs 11-12] from the index sample `(n, grad)` already taken at
/// `s.x` (the eye rays', which gather [Ihrke07 eq 1] from that sample first).
#[inline(always)]
pub fn step_euler_sampled(s: &mut RayState, (n, grad): (f64, DVec3), h: f64) {
    s.x += s.v * (h / n);
    s.v += grad * h;
    s.opl += n * h;
}

/// One classical RK4 step of size `h`.
#[inline]
pub fn step_rk4<F: IndexField + ?Sized>(f: &F, form: Form, s: &mut RayState, h: f64) {
    let mut k = [Deriv::ZERO; 4];
    for stage in 0..4 {
        let t = rk4_stage_point(s, &k, stage, h);
        k[stage] = deriv(f, form, t.x, t.v);
    }
    rk4_combine(s, &k, h);
}

/// Put `s` back on the eikonal shell `|v| = n` (keeping its direction),
/// with `n = sample.0` taken at `s.x`. In exact arithmetic the ray
/// equation keeps `|v| = n`; numerically `|v|` drifts where the sampled
/// gradient is not exactly that of the sampled n (thin, tilted
/// interfaces), and in the equal-time form that drift is a drift of
/// optical path: corners launched together would leave their wavefront.
#[inline(always)]
fn onto_shell(s: &mut RayState, n: f64) {
    let len = s.v.length();
    if len > 0.0 {
        s.v *= n / len;
    }
}

/// One RK4 step that starts by putting the state on the eikonal shell
/// `|v| = n`, reusing the index sample of its first stage (no extra cost).
/// Particles of one wavefront stepped with it in the equal-time form
/// [Ihrke07 eqs 14-15] all travel exactly `h` of optical path per step.
#[inline]
pub fn step_rk4_on_shell<F: IndexField + ?Sized>(f: &F, form: Form, s: &mut RayState, h: f64) {
    let (n, g) = f.sample(s.x);
    onto_shell(s, n);
    let mut k = [Deriv::ZERO; 4];
    k[0] = rhs(form, n, g, s.v);
    for stage in 1..4 {
        let t = rk4_stage_point(s, &k, stage, h);
        k[stage] = deriv(f, form, t.x, t.v);
    }
    rk4_combine(s, &k, h);
}

/// Forward Euler after putting the state on the eikonal shell (see
/// [`step_rk4_on_shell`]).
#[inline]
pub fn step_euler_on_shell<F: IndexField + ?Sized>(f: &F, form: Form, s: &mut RayState, h: f64) {
    let (n, g) = f.sample(s.x);
    onto_shell(s, n);
    *s = apply(s, &rhs(form, n, g, s.v), h);
}

/// Where RK4 evaluates its `stage`-th slope, given the earlier slopes.
#[inline(always)]
fn rk4_stage_point(s: &RayState, k: &[Deriv; 4], stage: usize, h: f64) -> RayState {
    match stage {
        0 => *s,
        1 => apply(s, &k[0], 0.5 * h),
        2 => apply(s, &k[1], 0.5 * h),
        _ => apply(s, &k[2], h),
    }
}

/// The RK4 update from the four slopes.
#[inline(always)]
fn rk4_combine(s: &mut RayState, k: &[Deriv; 4], h: f64) {
    let w = h / 6.0;
    s.x += (k[0].x + (k[1].x + k[2].x) * 2.0 + k[3].x) * w;
    s.v += (k[0].v + (k[1].v + k[2].v) * 2.0 + k[3].v) * w;
    s.opl += (k[0].opl + 2.0 * (k[1].opl + k[2].opl) + k[3].opl) * w;
}

/// Result of one attempted adaptive step.
#[derive(Clone, Copy, Debug)]
pub struct AdaptiveStep {
    /// Whether the step was taken (the state was advanced by `h_done`).
    pub accepted: bool,
    /// Size of the step taken (0 when rejected).
    pub h_done: f64,
    /// Suggested size for the next attempt.
    pub h_next: f64,
}

// Dormand-Prince 5(4) tableau.
const DP_A: [[f64; 6]; 6] = [
    [1.0 / 5.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.0 / 40.0, 9.0 / 40.0, 0.0, 0.0, 0.0, 0.0],
    [44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0, 0.0, 0.0, 0.0],
    [
        19372.0 / 6561.0,
        -25360.0 / 2187.0,
        64448.0 / 6561.0,
        -212.0 / 729.0,
        0.0,
        0.0,
    ],
    [
        9017.0 / 3168.0,
        -355.0 / 33.0,
        46732.0 / 5247.0,
        49.0 / 176.0,
        -5103.0 / 18656.0,
        0.0,
    ],
    [
        35.0 / 384.0,
        0.0,
        500.0 / 1113.0,
        125.0 / 192.0,
        -2187.0 / 6784.0,
        11.0 / 84.0,
    ],
];
// Fifth-order weights minus embedded fourth-order weights.
const DP_E: [f64; 7] = [
    71.0 / 57600.0,
    0.0,
    -71.0 / 16695.0,
    71.0 / 1920.0,
    -17253.0 / 339200.0,
    22.0 / 525.0,
    -1.0 / 40.0,
];

/// One Dormand-Prince 5(4) attempt of size `h`. The local error estimate is
/// held below `tol_x` in position (world units) and `tol_v` in `v` (index
/// units); `h_max` caps the step.
pub fn step_dopri<F: IndexField + ?Sized>(
    f: &F,
    form: Form,
    s: &mut RayState,
    h: f64,
    tol_x: f64,
    tol_v: f64,
    h_max: f64,
) -> AdaptiveStep {
    let mut k = [Deriv::ZERO; 7];
    k[0] = deriv(f, form, s.x, s.v);
    let mut y = *s;
    for (stage, a) in DP_A.iter().enumerate() {
        let mut t = *s;
        for (j, &aj) in a.iter().enumerate().take(stage + 1) {
            if aj != 0.0 {
                t = apply(&t, &k[j], aj * h);
            }
        }
        k[stage + 1] = deriv(f, form, t.x, t.v);
        y = t;
    }
    // The last stage point is the fifth-order solution (FSAL property).
    let mut ex = DVec3::ZERO;
    let mut ev = DVec3::ZERO;
    for (kj, &e) in k.iter().zip(DP_E.iter()) {
        ex += kj.x * (e * h);
        ev += kj.v * (e * h);
    }
    let err = (ex.length() / tol_x).max(ev.length() / tol_v);
    let grow = if err == 0.0 {
        5.0
    } else {
        (0.9 * err.powf(-0.2)).clamp(0.2, 5.0)
    };
    let h_next = (h * grow).min(h_max);
    // Steps far below the cap are accepted regardless so a ray can never
    // stall; the tolerance is then unreachable in double precision anyway.
    if err <= 1.0 || h <= h_max * 1e-9 {
        *s = y;
        AdaptiveStep {
            accepted: true,
            h_done: h,
            h_next,
        }
    } else {
        AdaptiveStep {
            accepted: false,
            h_done: 0.0,
            h_next,
        }
    }
}

/// How a traced ray ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    /// Left the volume bounds; position and direction are the exit.
    Exited,
    /// Took `max_steps` steps without leaving (trapped, or the guard is too low).
    MaxSteps,
    /// Started outside and never meets the bounds.
    Missed,
    /// The state became non-finite (a field with n <= 0, or a bad step).
    Diverged,
}

impl Status {
    /// Lower-case name used in CLI output.
    pub fn name(self) -> &'static str {
        match self {
            Status::Exited => "exited",
            Status::MaxSteps => "max-steps",
            Status::Missed => "missed",
            Status::Diverged => "diverged",
        }
    }
}

/// Settings for [`trace`].
#[derive(Clone, Copy, Debug)]
pub struct TraceOptions {
    /// Parameterization.
    pub form: Form,
    /// Integrator.
    pub integrator: Integrator,
    /// Step in world units (distance for equal distance, optical path for
    /// equal time); the largest step for Dormand-Prince.
    pub step: f64,
    /// Dormand-Prince local error target: position in world units (the
    /// direction error target is `tolerance / step` in index units).
    pub tolerance: f64,
    /// Guard: give up after this many accepted steps.
    pub max_steps: usize,
    /// Keep every accepted position in [`RayEnd::path`].
    pub record_path: bool,
}

impl TraceOptions {
    /// Options with the step given in voxels of `grid` (its smallest cell
    /// edge), a Dormand-Prince tolerance of 1e-4 voxel, a guard of a
    /// million steps and no path recording.
    pub fn in_voxels(
        grid: &GridGeometry,
        form: Form,
        integrator: Integrator,
        step_voxels: f64,
    ) -> Self {
        let h = grid.voxel_size();
        Self {
            form,
            integrator,
            step: step_voxels * h,
            tolerance: 1e-4 * h,
            max_steps: 1_000_000,
            record_path: false,
        }
    }
}

/// How a ray ended, where, and how it got there.
#[derive(Clone, Debug)]
pub struct RayEnd {
    /// Why the trace stopped.
    pub status: Status,
    /// Where the ray entered the bounds (its origin when it started inside).
    pub entry: DVec3,
    /// Exit point on the bounds, or the last position for other statuses.
    pub position: DVec3,
    /// Unit direction at `position`.
    pub direction: DVec3,
    /// Optical path length `int n ds` from `entry` to `position`.
    pub optical_path: f64,
    /// Number of accepted steps (a final partial step counts as one).
    pub steps: usize,
    /// Rejected Dormand-Prince attempts.
    pub rejected: usize,
    /// Accepted positions from `entry` to `position`, if recorded.
    pub path: Vec<DVec3>,
}

/// One ray being marched: its state and the record of how it is going.
struct March {
    s: RayState,
    h: f64,
    end: RayEnd,
}

impl March {
    /// Set a ray up at the bounds; `Err` carries a ray that ended before its
    /// first step (it missed the bounds, or its input was not finite).
    fn start<F: IndexField + ?Sized>(
        field: &F,
        grid: &GridGeometry,
        origin: DVec3,
        dir: DVec3,
        opts: &TraceOptions,
    ) -> Result<March, Box<RayEnd>> {
        let d = dir.normalize_or_zero();
        let mut end = RayEnd {
            status: Status::Missed,
            entry: origin,
            position: origin,
            direction: d,
            optical_path: 0.0,
            steps: 0,
            rejected: 0,
            path: Vec::new(),
        };
        if d == DVec3::ZERO || !origin.is_finite() || !d.is_finite() {
            end.status = Status::Diverged;
            return Err(Box::new(end));
        }
        let start = if grid.contains(origin) {
            origin
        } else {
            match grid.clip_line(origin, d) {
                Some((t0, t1)) if t1 >= 0.0 && t0 >= 0.0 => origin + d * t0,
                _ => return Err(Box::new(end)),
            }
        };
        end.entry = start;
        if opts.record_path {
            end.path.push(start);
        }
        Ok(March {
            s: RayState::new(start, d, field.sample(start).0),
            h: opts.step,
            end,
        })
    }

    /// Take one step; true once the ray has ended (then `end` is complete).
    #[inline(always)]
    fn advance<F: IndexField + ?Sized>(
        &mut self,
        field: &F,
        grid: &GridGeometry,
        opts: &TraceOptions,
    ) -> bool {
        if self.out_of_steps(opts) {
            return true;
        }
        let prev = self.s;
        let end = &mut self.end;
        let s = &mut self.s;
        let h_used = match opts.integrator {
            Integrator::Euler => {
                step_euler(field, opts.form, s, self.h);
                self.h
            }
            Integrator::Rk4 => {
                step_rk4(field, opts.form, s, self.h);
                self.h
            }
            Integrator::DormandPrince => {
                let tol_v = opts.tolerance / opts.step;
                let r = step_dopri(
                    field,
                    opts.form,
                    s,
                    self.h,
                    opts.tolerance,
                    tol_v,
                    opts.step,
                );
                self.h = r.h_next;
                if !r.accepted {
                    end.rejected += 1;
                    if self.h.is_finite() {
                        return false;
                    }
                    // A non-finite suggested step means the state blew up.
                    end.status = Status::Diverged;
                    end.position = prev.x;
                    end.direction = prev.v.normalize_or_zero();
                    end.optical_path = prev.opl;
                    return true;
                }
                r.h_done
            }
        };
        self.settle(field, grid, opts, &prev, h_used)
    }

    /// The `max_steps` guard: true (and the end recorded) once reached.
    #[inline(always)]
    fn out_of_steps(&mut self, opts: &TraceOptions) -> bool {
        let end = &mut self.end;
        if end.steps < opts.max_steps {
            return false;
        }
        end.status = Status::MaxSteps;
        end.position = self.s.x;
        end.direction = self.s.direction();
        end.optical_path = self.s.opl;
        true
    }

    /// Book-keeping after a step of size `h_used` from `prev`: record the
    /// point, or detect the exit or a blow-up; true once the ray has ended.
    #[inline(always)]
    fn settle<F: IndexField + ?Sized>(
        &mut self,
        field: &F,
        grid: &GridGeometry,
        opts: &TraceOptions,
        prev: &RayState,
        h_used: f64,
    ) -> bool {
        let end = &mut self.end;
        let s = &self.s;
        end.steps += 1;
        // A non-finite position fails the containment test too, so the
        // finiteness check costs nothing on the common path.
        if grid.contains(s.x) {
            if opts.record_path {
                end.path.push(s.x);
            }
            return false;
        }
        if !(s.x.is_finite() && s.v.is_finite() && s.opl.is_finite()) {
            end.status = Status::Diverged;
            end.position = prev.x;
            end.direction = prev.v.normalize_or_zero();
            end.optical_path = prev.opl;
            return true;
        }
        let (t, position) = exit_point(field, opts.form, grid, prev, s, h_used);
        end.status = Status::Exited;
        end.position = position;
        end.direction = prev.v.lerp(s.v, t).normalize();
        end.optical_path = prev.opl + (s.opl - prev.opl) * t;
        if opts.record_path {
            end.path.push(end.position);
        }
        true
    }
}

/// Where a step from `a` to `b` (of size `h`) leaves the bounds: the step's
/// fraction `t` and the point. The path over the step is taken as the cubic
/// Hermite curve through both ends with their tangents `dx/dparam`, which is
/// as accurate as the integrators' own steps; the straight chord would make
/// the exit point only second-order accurate.
fn exit_point<F: IndexField + ?Sized>(
    field: &F,
    form: Form,
    grid: &GridGeometry,
    a: &RayState,
    b: &RayState,
    h: f64,
) -> (f64, DVec3) {
    let chord = b.x - a.x;
    let t_chord = grid
        .clip_line(a.x, chord)
        .map_or(1.0, |(_, t1)| t1.clamp(0.0, 1.0));
    let q = a.x + chord * t_chord;
    // The face the chord leaves through: the bound nearest the chord's exit.
    let (mut axis, mut bound, mut gap) = (0, grid.max.x, f64::INFINITY);
    for ax in 0..3 {
        for side in [grid.min[ax], grid.max[ax]] {
            if (q[ax] - side).abs() < gap {
                (axis, bound, gap) = (ax, side, (q[ax] - side).abs());
            }
        }
    }
    let ma = deriv(field, form, a.x, a.v).x * h;
    let mb = deriv(field, form, b.x, b.v).x * h;
    let hermite = |t: f64| {
        let (t2, t3) = (t * t, t * t * t);
        a.x * (2.0 * t3 - 3.0 * t2 + 1.0)
            + ma * (t3 - 2.0 * t2 + t)
            + b.x * (-2.0 * t3 + 3.0 * t2)
            + mb * (t3 - t2)
    };
    let slope = |t: f64| {
        let t2 = t * t;
        a.x * (6.0 * t2 - 6.0 * t)
            + ma * (3.0 * t2 - 4.0 * t + 1.0)
            + b.x * (-6.0 * t2 + 6.0 * t)
            + mb * (3.0 * t2 - 2.0 * t)
    };
    let mut t = t_chord;
    for _ in 0..6 {
        let d = slope(t)[axis];
        if d == 0.0 {
            break;
        }
        t -= (hermite(t)[axis] - bound) / d;
    }
    if !(0.0..=1.0).contains(&t) {
        // The cubic disagrees with the chord about the face: keep the chord.
        return (t_chord, q);
    }
    let mut p = hermite(t);
    p[axis] = bound;
    (t, p.clamp(grid.min, grid.max))
}

/// March a ray from `origin` along `dir` through `field` until it leaves the
/// bounds of `grid` (or a guard stops it). A ray starting outside first
/// travels straight to the bounds.
pub fn trace<F: IndexField + ?Sized>(
    field: &F,
    grid: &GridGeometry,
    origin: DVec3,
    dir: DVec3,
    opts: &TraceOptions,
) -> RayEnd {
    match March::start(field, grid, origin, dir, opts) {
        Err(end) => *end,
        Ok(mut m) => {
            while !m.advance(field, grid, opts) {}
            m.end
        }
    }
}

/// Rays marched together by [`trace_many`].
const LANES: usize = 8;

/// One RK4 step of every busy lane, stage by stage across the lanes so the
/// lanes' field samples are independent work the processor can overlap (a
/// whole RK4 step per lane is too long for it to look past).
fn rk4_lockstep<F: IndexField + ?Sized>(
    field: &F,
    grid: &GridGeometry,
    opts: &TraceOptions,
    lanes: &mut [Option<(usize, March)>; LANES],
    finished: &mut [bool; LANES],
) {
    let mut k = [[Deriv::ZERO; 4]; LANES];
    let mut live = [false; LANES];
    for (l, lane) in lanes.iter_mut().enumerate() {
        if let Some((_, m)) = lane {
            finished[l] = m.out_of_steps(opts);
            live[l] = !finished[l];
        }
    }
    for stage in 0..4 {
        for (l, lane) in lanes.iter().enumerate() {
            if let (true, Some((_, m))) = (live[l], lane) {
                let t = rk4_stage_point(&m.s, &k[l], stage, m.h);
                k[l][stage] = deriv(field, opts.form, t.x, t.v);
            }
        }
    }
    for (l, lane) in lanes.iter_mut().enumerate() {
        if let (true, Some((_, m))) = (live[l], lane) {
            let prev = m.s;
            rk4_combine(&mut m.s, &k[l], m.h);
            finished[l] = m.settle(field, grid, opts, &prev, m.h);
        }
    }
}

/// Trace many rays `(origin, direction)`; results are in input order and
/// identical to calling [`trace`] on each. One ray's steps form a chain of
/// dependent operations (sample, then step, then sample again), so a lone
/// ray leaves the processor waiting on latency; marching `LANES` independent
/// rays round-robin lets their chains overlap.
pub fn trace_many<F: IndexField + ?Sized>(
    field: &F,
    grid: &GridGeometry,
    rays: &[(DVec3, DVec3)],
    opts: &TraceOptions,
) -> Vec<RayEnd> {
    let mut out: Vec<Option<RayEnd>> = vec![None; rays.len()];
    let mut lanes: [Option<(usize, March)>; LANES] = std::array::from_fn(|_| None);
    let mut next = 0;
    let mut refill = |lane: &mut Option<(usize, March)>, out: &mut [Option<RayEnd>]| {
        *lane = None;
        while next < rays.len() {
            let i = next;
            next += 1;
            match March::start(field, grid, rays[i].0, rays[i].1, opts) {
                Ok(m) => {
                    *lane = Some((i, m));
                    return;
                }
                Err(end) => out[i] = Some(*end),
            }
        }
    };
    for lane in lanes.iter_mut() {
        refill(lane, &mut out);
    }
    let mut finished = [false; LANES];
    loop {
        if opts.integrator == Integrator::Rk4 {
            rk4_lockstep(field, grid, opts, &mut lanes, &mut finished);
        } else {
            for (lane, done) in lanes.iter_mut().zip(finished.iter_mut()) {
                if let Some((_, m)) = lane {
                    *done = m.advance(field, grid, opts);
                }
            }
        }
        let mut busy = false;
        for (lane, done) in lanes.iter_mut().zip(finished.iter_mut()) {
            if std::mem::take(done) {
                let (i, m) = lane.take().expect("a finished lane was busy");
                out[i] = Some(m.end);
                refill(lane, &mut out);
            }
            busy |= lane.is_some();
        }
        if !busy {
            break;
        }
    }
    out.into_iter()
        .map(|e| e.expect("every ray ends"))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Uniform(f64);
    impl IndexField for Uniform {
        fn sample(&self, _: DVec3) -> (f64, DVec3) {
            (self.0, DVec3::ZERO)
        }
    }

    fn opts(integrator: Integrator) -> TraceOptions {
        TraceOptions {
            form: Form::EqualDistance,
            integrator,
            step: 0.01,
            tolerance: 1e-9,
            max_steps: 100_000,
            record_path: true,
        }
    }

    #[test]
    fn missed_and_guarded_rays_are_reported() {
        let g = GridGeometry::new([8, 8, 8], DVec3::ZERO, DVec3::ONE);
        let r = trace(
            &Uniform(1.0),
            &g,
            DVec3::new(-1.0, 2.0, 0.5),
            DVec3::X,
            &opts(Integrator::Rk4),
        );
        assert_eq!(r.status, Status::Missed);
        let mut o = opts(Integrator::Euler);
        o.max_steps = 10;
        let r = trace(&Uniform(1.0), &g, DVec3::splat(0.5), DVec3::X, &o);
        assert_eq!(r.status, Status::MaxSteps);
        assert_eq!(r.steps, 10);
        assert!((r.position.x - 0.6).abs() < 1e-12);
    }

    /// A smooth lens-like field for comparing batch and single traces.
    struct Bump;
    impl IndexField for Bump {
        fn sample(&self, p: DVec3) -> (f64, DVec3) {
            let q = p - DVec3::splat(0.5);
            let e = (-8.0 * q.length_squared()).exp();
            (1.0 + 0.4 * e, q * (-16.0 * 0.4 * e))
        }
    }

    #[test]
    fn trace_many_matches_trace_bit_for_bit() {
        let g = GridGeometry::new([8, 8, 8], DVec3::ZERO, DVec3::ONE);
        let rays: Vec<(DVec3, DVec3)> = (0..37)
            .map(|i| {
                let y = i as f64 / 36.0;
                // Some rays miss, some start inside, all others cross the bump.
                let o = if i % 9 == 0 {
                    DVec3::new(-1.0, 5.0, 0.5)
                } else {
                    DVec3::new(-0.2, y, 0.45)
                };
                (o, DVec3::new(1.0, 0.1 * (y - 0.5), 0.05))
            })
            .collect();
        for m in [
            Integrator::Euler,
            Integrator::Rk4,
            Integrator::DormandPrince,
        ] {
            let mut o = opts(m);
            o.tolerance = 1e-6;
            o.max_steps = if m == Integrator::Euler { 50 } else { 100_000 };
            let batch = trace_many(&Bump, &g, &rays, &o);
            for (r, b) in rays.iter().zip(&batch) {
                let single = trace(&Bump, &g, r.0, r.1, &o);
                assert_eq!(single.status, b.status);
                assert_eq!(single.position, b.position);
                assert_eq!(single.path, b.path);
                assert_eq!(single.steps, b.steps);
            }
            assert!(batch.iter().any(|e| e.status == Status::Missed));
        }
    }

    #[test]
    fn exit_point_and_optical_path_in_uniform_glass() {
        let g = GridGeometry::new([8, 8, 8], DVec3::ZERO, DVec3::ONE);
        for m in [
            Integrator::Euler,
            Integrator::Rk4,
            Integrator::DormandPrince,
        ] {
            for form in [Form::EqualDistance, Form::EqualTime] {
                let mut o = opts(m);
                o.form = form;
                let r = trace(&Uniform(1.5), &g, DVec3::new(-0.5, 0.5, 0.5), DVec3::X, &o);
                assert_eq!(r.status, Status::Exited);
                assert!((r.position - DVec3::new(1.0, 0.5, 0.5)).length() < 1e-12);
                assert!(
                    (r.optical_path - 1.5).abs() < 1e-12,
                    "{m:?} {form:?} {}",
                    r.optical_path
                );
            }
        }
    }
}
