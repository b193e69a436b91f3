//! Interval arithmetic with outward rounding, for the Krawczyk test of
//! [Walter09 sec 3.3.2] ([Walter09 eqs 11-15]).
//!
//! An [`Interval`] `[lo, hi]` stands for every real number between its
//! bounds. Each arithmetic operation computes its bounds in ordinary
//! round-to-nearest `f64` arithmetic and then widens the result by one unit
//! in the last place on each side ([`next_down`] on the lower bound,
//! [`next_up`] on the upper). A correctly rounded result lies within half an
//! ulp of the exact value, so the widened interval always contains the exact
//! real result of the operation applied to any reals taken from the
//! operands (the *enclosure property*, tested below with error-free
//! transformations). This costs a few ulps of width per operation but needs
//! no control of the FPU rounding mode.
//!
//! Anything that cannot be bounded (a NaN bound, division by an interval
//! that contains zero) gives [`Interval::ENTIRE`], `[-inf, +inf]`, which is
//! always a valid enclosure.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// The smallest `f64` greater than `x` (`+inf` stays `+inf`, NaN stays NaN).
///
/// Same as `f64::next_up`, which is stable only since Rust 1.86; the
/// workspace supports 1.85, so this steps the bit pattern directly.
pub fn next_up(x: f64) -> f64 {
    if x.is_nan() || x == f64::INFINITY {
        return x;
    }
    if x == 0.0 {
        // Both +0 and -0: the smallest positive subnormal.
        return f64::from_bits(1);
    }
    let bits = x.to_bits();
    if x > 0.0 {
        f64::from_bits(bits + 1)
    } else {
        f64::from_bits(bits - 1)
    }
}

/// The largest `f64` less than `x` (`-inf` stays `-inf`, NaN stays NaN).
pub fn next_down(x: f64) -> f64 {
    -next_up(-x)
}

/// A closed interval `[lo, hi]` of reals with `lo <= hi` (bounds may be
/// infinite). See the module documentation for the rounding rules.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    lo: f64,
    hi: f64,
}

impl Interval {
    /// `[-inf, +inf]`: the enclosure of last resort.
    pub const ENTIRE: Interval = Interval {
        lo: f64::NEG_INFINITY,
        hi: f64::INFINITY,
    };

    /// The interval `[lo, hi]`. A NaN bound gives [`Interval::ENTIRE`].
    ///
    /// # Panics
    /// If `lo > hi`.
    pub fn new(lo: f64, hi: f64) -> Interval {
        if lo.is_nan() || hi.is_nan() {
            return Interval::ENTIRE;
        }
        assert!(lo <= hi, "interval bounds out of order: [{lo}, {hi}]");
        Interval { lo, hi }
    }

    /// The degenerate interval `[x, x]` (exact: no widening).
    pub fn point(x: f64) -> Interval {
        Interval::new(x, x)
    }

    /// Bounds computed in round-to-nearest, widened by one ulp each side.
    fn outward(lo: f64, hi: f64) -> Interval {
        if lo.is_nan() || hi.is_nan() {
            return Interval::ENTIRE;
        }
        Interval {
            lo: next_down(lo),
            hi: next_up(hi),
        }
    }

    /// Lower bound.
    pub fn lo(self) -> f64 {
        self.lo
    }

    /// Upper bound.
    pub fn hi(self) -> f64 {
        self.hi
    }

    /// The midpoint, a float inside the interval (the operator `m(·)` of
    /// [Walter09 eq 11]). Infinite bounds give a finite or infinite float;
    /// callers use it only on bounded intervals.
    pub fn mid(self) -> f64 {
        let m = 0.5 * self.lo + 0.5 * self.hi;
        m.clamp(self.lo, self.hi)
    }

    /// `hi - lo` (rounded to nearest; for sizes, not for enclosures).
    pub fn width(self) -> f64 {
        self.hi - self.lo
    }

    /// Magnitude `max(|lo|, |hi|)`, the largest absolute value in it.
    pub fn mag(self) -> f64 {
        self.lo.abs().max(self.hi.abs())
    }

    /// Whether `x` lies in the interval.
    pub fn contains(self, x: f64) -> bool {
        self.lo <= x && x <= self.hi
    }

    /// Whether `self ⊆ other`.
    pub fn subset_of(self, other: Interval) -> bool {
        other.lo <= self.lo && self.hi <= other.hi
    }

    /// The intersection, `None` when empty (used by [Walter09 eqs 13 and 14]).
    pub fn intersect(self, other: Interval) -> Option<Interval> {
        let lo = self.lo.max(other.lo);
        let hi = self.hi.min(other.hi);
        (lo <= hi).then_some(Interval { lo, hi })
    }

    /// The smallest interval containing both.
    pub fn hull(self, other: Interval) -> Interval {
        Interval {
            lo: self.lo.min(other.lo),
            hi: self.hi.max(other.hi),
        }
    }

    /// `{x² : x ∈ self}`, tighter than `self * self` when the interval
    /// straddles zero.
    pub fn sqr(self) -> Interval {
        if self.lo >= 0.0 {
            Interval::outward(self.lo * self.lo, self.hi * self.hi)
        } else if self.hi <= 0.0 {
            Interval::outward(self.hi * self.hi, self.lo * self.lo)
        } else {
            let m = self.mag();
            Interval {
                lo: 0.0,
                hi: next_up(m * m),
            }
        }
    }

    /// `{√x : x ∈ self, x >= 0}`. Negative parts are ignored: the solver
    /// takes roots only of sums of squares, which are non-negative as reals.
    /// An interval entirely below zero gives [`Interval::ENTIRE`].
    pub fn sqrt(self) -> Interval {
        if self.hi < 0.0 {
            return Interval::ENTIRE;
        }
        let lo = next_down(self.lo.max(0.0).sqrt()).max(0.0);
        Interval {
            lo,
            hi: next_up(self.hi.sqrt()),
        }
    }

    /// Intersection with `[-1, 1]`, valid for a component of a unit vector;
    /// if the intersection is empty (impossible for a correct enclosure)
    /// the interval is returned unchanged.
    pub fn clamp_unit(self) -> Interval {
        self.intersect(Interval { lo: -1.0, hi: 1.0 })
            .unwrap_or(self)
    }
}

impl Add for Interval {
    type Output = Interval;
    fn add(self, o: Interval) -> Interval {
        Interval::outward(self.lo + o.lo, self.hi + o.hi)
    }
}

impl Sub for Interval {
    type Output = Interval;
    fn sub(self, o: Interval) -> Interval {
        Interval::outward(self.lo - o.hi, self.hi - o.lo)
    }
}

impl Neg for Interval {
    type Output = Interval;
    fn neg(self) -> Interval {
        // Exact.
        Interval {
            lo: -self.hi,
            hi: -self.lo,
        }
    }
}

impl Mul for Interval {
    type Output = Interval;
    fn mul(self, o: Interval) -> Interval {
        let p = [
            self.lo * o.lo,
            self.lo * o.hi,
            self.hi * o.lo,
            self.hi * o.hi,
        ];
        if p.iter().any(|x| x.is_nan()) {
            // 0 · ∞: give up rather than guess.
            return Interval::ENTIRE;
        }
        let lo = p.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Interval::outward(lo, hi)
    }
}

impl Div for Interval {
    type Output = Interval;
    fn div(self, o: Interval) -> Interval {
        if o.lo <= 0.0 && o.hi >= 0.0 {
            return Interval::ENTIRE;
        }
        let q = [
            self.lo / o.lo,
            self.lo / o.hi,
            self.hi / o.lo,
            self.hi / o.hi,
        ];
        if q.iter().any(|x| x.is_nan()) {
            return Interval::ENTIRE;
        }
        let lo = q.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = q.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Interval::outward(lo, hi)
    }
}

impl Add<f64> for Interval {
    type Output = Interval;
    fn add(self, o: f64) -> Interval {
        self + Interval::point(o)
    }
}

impl Sub<f64> for Interval {
    type Output = Interval;
    fn sub(self, o: f64) -> Interval {
        self - Interval::point(o)
    }
}

impl Mul<f64> for Interval {
    type Output = Interval;
    fn mul(self, o: f64) -> Interval {
        self * Interval::point(o)
    }
}

/// Arithmetic shared by `f64` and [`Interval`], so that the solver's target
/// function [Walter09 eq 8] and its Jacobian are written once and evaluated
/// either at a point (Newton, [Walter09 eq 9]) or over a box (Krawczyk,
/// [Walter09 eqs 11-15]).
pub(crate) trait Scalar:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// The exact value `x`.
    fn cst(x: f64) -> Self;
    /// Square root (of a non-negative quantity).
    fn root(self) -> Self;
    /// Square.
    fn square(self) -> Self;
    /// Restrict to `[-1, 1]` (a component of a unit vector); the identity on
    /// floats.
    fn unit_clamp(self) -> Self;
}

impl Scalar for f64 {
    fn cst(x: f64) -> f64 {
        x
    }
    fn root(self) -> f64 {
        self.sqrt()
    }
    fn square(self) -> f64 {
        self * self
    }
    fn unit_clamp(self) -> f64 {
        self
    }
}

impl Scalar for Interval {
    fn cst(x: f64) -> Interval {
        Interval::point(x)
    }
    fn root(self) -> Interval {
        self.sqrt()
    }
    fn square(self) -> Interval {
        self.sqr()
    }
    fn unit_clamp(self) -> Interval {
        self.clamp_unit()
    }
}

/// A 3-vector over a [`Scalar`].
#[derive(Debug, Clone, Copy)]
pub(crate) struct V3<T> {
    pub x: T,
    pub y: T,
    pub z: T,
}

impl<T: Scalar> V3<T> {
    pub fn from_dvec(v: glam::DVec3) -> V3<T> {
        V3 {
            x: T::cst(v.x),
            y: T::cst(v.y),
            z: T::cst(v.z),
        }
    }
    pub fn add(self, o: V3<T>) -> V3<T> {
        V3 {
            x: self.x + o.x,
            y: self.y + o.y,
            z: self.z + o.z,
        }
    }
    pub fn sub(self, o: V3<T>) -> V3<T> {
        V3 {
            x: self.x - o.x,
            y: self.y - o.y,
            z: self.z - o.z,
        }
    }
    pub fn scale(self, s: T) -> V3<T> {
        V3 {
            x: self.x * s,
            y: self.y * s,
            z: self.z * s,
        }
    }
    pub fn div(self, s: T) -> V3<T> {
        V3 {
            x: self.x / s,
            y: self.y / s,
            z: self.z / s,
        }
    }
    pub fn dot(self, o: V3<T>) -> T {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    pub fn cross(self, o: V3<T>) -> V3<T> {
        V3 {
            x: self.y * o.z - self.z * o.y,
            y: self.z * o.x - self.x * o.z,
            z: self.x * o.y - self.y * o.x,
        }
    }
    pub fn neg(self) -> V3<T> {
        V3 {
            x: -self.x,
            y: -self.y,
            z: -self.z,
        }
    }
    pub fn norm(self) -> T {
        (self.x.square() + self.y.square() + self.z.square()).root()
    }
    pub fn unit_clamp(self) -> V3<T> {
        V3 {
            x: self.x.unit_clamp(),
            y: self.y.unit_clamp(),
            z: self.z.unit_clamp(),
        }
    }
}

impl V3<f64> {
    pub fn to_dvec(self) -> glam::DVec3 {
        glam::DVec3::new(self.x, self.y, self.z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SplitMix64 with the draws these tests need.
    struct Rng(eikon_rng::SplitMix64);
    impl Rng {
        /// A float of either sign spread over many binades, sometimes 0.
        fn wide(&mut self) -> f64 {
            match self.0.next_u64() % 8 {
                0 => 0.0,
                1 => (self.0.unit() - 0.5) * 2.0,
                _ => {
                    let e = (self.0.next_u64() % 41) as i32 - 20;
                    let s = if self.0.next_u64().is_multiple_of(2) {
                        1.0
                    } else {
                        -1.0
                    };
                    s * (1.0 + self.0.unit()) * 2f64.powi(e)
                }
            }
        }
        fn interval(&mut self) -> Interval {
            let a = self.wide();
            let b = match self.0.next_u64() % 3 {
                0 => a,                                   // degenerate
                1 => a + self.0.unit() * a.abs() * 1e-10, // thin
                _ => self.wide(),
            };
            Interval::new(a.min(b), a.max(b))
        }
        fn sample(&mut self, x: Interval) -> f64 {
            match self.0.next_u64() % 4 {
                0 => x.lo(),
                1 => x.hi(),
                _ => (x.lo() + self.0.unit() * (x.hi() - x.lo())).clamp(x.lo(), x.hi()),
            }
        }
    }

    /// An exact real `r + e` (an unevaluated sum of two floats with
    /// `r = fl(r + e)`), or `q + sign` when only the sign of the error is
    /// known. `sign` is the sign of `exact − r`.
    #[derive(Clone, Copy)]
    struct Exact {
        r: f64,
        sign: f64,
    }

    /// `lo <= exact` decided exactly. If `r > lo`, the exact value is at
    /// least the midpoint between `r` and its predecessor (round to nearest),
    /// which is above `pred(r) >= lo`; if `r == lo` the sign decides.
    fn ge(x: Exact, lo: f64) -> bool {
        x.r > lo || (x.r == lo && x.sign >= 0.0)
    }
    fn le(x: Exact, hi: f64) -> bool {
        x.r < hi || (x.r == hi && x.sign <= 0.0)
    }
    fn inside(x: Exact, i: Interval) -> bool {
        ge(x, i.lo()) && le(x, i.hi())
    }

    /// Error-free transformations (Knuth's TwoSum, FMA-based products,
    /// division and square-root remainders).
    fn exact_add(a: f64, b: f64) -> Exact {
        let s = a + b;
        let bb = s - a;
        let e = (a - (s - bb)) + (b - bb);
        Exact { r: s, sign: e }
    }
    fn exact_mul(a: f64, b: f64) -> Exact {
        let p = a * b;
        Exact {
            r: p,
            sign: a.mul_add(b, -p),
        }
    }
    fn exact_div(a: f64, b: f64) -> Exact {
        let q = a / b;
        // a − q·b is exact (representable) and has the sign of b·(a/b − q).
        let r = (-q).mul_add(b, a);
        Exact {
            r: q,
            sign: r * b.signum(),
        }
    }
    fn exact_sqrt(a: f64) -> Exact {
        let s = a.sqrt();
        Exact {
            r: s,
            sign: (-s).mul_add(s, a),
        }
    }

    #[test]
    fn ulp_steps() {
        assert_eq!(next_up(1.0), 1.0 + f64::EPSILON);
        assert_eq!(next_down(1.0), 1.0 - f64::EPSILON / 2.0);
        assert_eq!(next_up(0.0), f64::from_bits(1));
        assert_eq!(next_up(-0.0), f64::from_bits(1));
        assert_eq!(next_down(0.0), -f64::from_bits(1));
        assert_eq!(next_up(-f64::from_bits(1)), -0.0);
        assert_eq!(next_up(f64::MAX), f64::INFINITY);
        assert_eq!(next_up(f64::INFINITY), f64::INFINITY);
        assert_eq!(next_up(f64::NEG_INFINITY), -f64::MAX);
        assert_eq!(next_down(f64::NEG_INFINITY), f64::NEG_INFINITY);
        assert!(next_up(f64::NAN).is_nan());
        for x in [-3.5, -1e-300, 2.0, 1e300, 7.0e-310] {
            assert!(next_up(x) > x && next_down(x) < x);
            assert_eq!(next_down(next_up(x)), x);
        }
    }

    /// The enclosure property, checked exactly: for random operand intervals
    /// (degenerate, ulp-thin and wide, mixed signs, 40 binades) and sampled
    /// operands in them (both endpoints and interior points), the exact real
    /// result of `x op y` lies in `X op Y`. Exactness comes from
    /// error-free transformations, not from a second rounded evaluation.
    #[test]
    fn operations_enclose_exact_results() {
        let mut rng = Rng(eikon_rng::SplitMix64::new(0x5EED_1E55));
        let mut checked = 0usize;
        let mut max_rel_width = 0.0f64;
        for _ in 0..20_000 {
            let a = rng.interval();
            let b = rng.interval();
            let (sum, dif, prod, quot) = (a + b, a - b, a * b, a / b);
            let sq = a.sqr();
            let rt = a.sqrt();
            if a.lo() == a.hi() && b.lo() == b.hi() && a.lo() != 0.0 && b.lo() != 0.0 {
                let w = prod.width() / prod.mag();
                max_rel_width = max_rel_width.max(w);
            }
            for _ in 0..8 {
                let x = rng.sample(a);
                let y = rng.sample(b);
                assert!(inside(exact_add(x, y), sum), "{x} + {y} ∉ {sum:?}");
                assert!(inside(exact_add(x, -y), dif), "{x} - {y} ∉ {dif:?}");
                assert!(inside(exact_mul(x, y), prod), "{x} * {y} ∉ {prod:?}");
                assert!(inside(exact_mul(x, x), sq), "{x}² ∉ {sq:?}");
                if y != 0.0 {
                    assert!(inside(exact_div(x, y), quot), "{x} / {y} ∉ {quot:?}");
                } else {
                    assert_eq!(quot, Interval::ENTIRE);
                }
                if x >= 0.0 {
                    assert!(inside(exact_sqrt(x), rt), "√{x} ∉ {rt:?}");
                }
                checked += 7;
            }
        }
        println!(
            "interval enclosure: {checked} exact point checks passed; \
             point-product width ≤ {max_rel_width:.2e} relative"
        );
        // One ulp each side of a correctly rounded product: width ≤ 4 ulp.
        assert!(max_rel_width <= 4.0 * f64::EPSILON);
    }

    #[test]
    fn set_operations_and_special_cases() {
        let a = Interval::new(-1.0, 2.0);
        let b = Interval::new(1.5, 3.0);
        assert_eq!(a.intersect(b), Some(Interval::new(1.5, 2.0)));
        assert_eq!(a.intersect(Interval::new(2.5, 3.0)), None);
        assert_eq!(a.hull(b), Interval::new(-1.0, 3.0));
        assert!(Interval::new(0.0, 1.0).subset_of(a));
        assert!(!b.subset_of(a));
        assert_eq!(a / a, Interval::ENTIRE);
        assert_eq!(Interval::new(-4.0, -1.0).sqrt(), Interval::ENTIRE);
        assert_eq!(Interval::new(-2.0, 3.0).sqr().lo(), 0.0);
        assert!(Interval::new(-2.0, 3.0).sqr().contains(9.0));
        assert_eq!(
            Interval::new(0.5, 3.0).clamp_unit(),
            Interval::new(0.5, 1.0)
        );
        assert_eq!(Interval::new(0.0, 0.0) * Interval::ENTIRE, Interval::ENTIRE);
        assert_eq!(Interval::new(f64::NAN, 1.0), Interval::ENTIRE);
        assert!(a.contains(a.mid()) && a.mid() == 0.5);
        // Negation is exact.
        assert_eq!(-a, Interval::new(-2.0, 1.0));
    }
}
