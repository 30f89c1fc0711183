//! Forgetting: a map that lets old observations fade, so a changed scene is relearnt.
//!
//! Why it is exact and cheap: an observation made at time τ and weighed γ^(t−τ) at time t (γ = 2^(−1/h),
//! h the half-life) contributes to a voxel's count and scatter with that weight and not at all to its
//! mean's direction. Scaling every weight of a set by one factor leaves the weighted mean m unchanged and
//! multiplies n and S by the factor. So a voxel keeps (n, m, S) *as of the time it last changed*, and
//! whoever reads or merges it first multiplies n and S by γ^age ([`ObsStats::decay`]) — lazily, never a
//! pass over the map. Merging two stamped sets brings both to the later stamp and merges them (Chan's
//! formula); the result is the set of all their observations, each weighed γ^(t−τ), in any order.
//!
//! **The clock rule** (also in `wire_spec.md`): times are `u32` ticks of one mission clock shared by every
//! robot and the base station (frames at a common rate, or tenths of seconds — the half-life is given in
//! the same ticks); a voxel's stamp is the tick of its last change; merging takes the later stamp; reading
//! at tick t decays by t − stamp (a stamp in the future reads undecayed: clocks never run backwards on the
//! map). With forgetting off (the default) stamps are ignored and nothing changes.
//!
//! Where it runs: host maps keep a stamp per voxel; the on-device `LocalMap` takes its clock as a type
//! ([`MapClock`]): [`Timeless`] (the default) stores no stamp and links no forgetting code, [`Fading`] keeps
//! a `u32` tick per voxel (4 B) and forgets once given a half-life.

use crate::obs::ObsStats;

/// How fast a map forgets: the half-life of an observation's weight, in clock ticks.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Forgetting {
    half_life: f32,
}

impl Forgetting {
    /// Observations never fade (the default, and the paper's map).
    pub const OFF: Option<Self> = None;

    /// Forget with the given half-life in ticks; `None` unless it is finite and > 0.
    pub fn new(half_life_ticks: f32) -> Option<Self> {
        (half_life_ticks > 0.0 && half_life_ticks.is_finite()).then_some(Self {
            half_life: half_life_ticks,
        })
    }

    /// The half-life, in ticks.
    pub fn half_life(&self) -> f32 {
        self.half_life
    }

    /// γ^age = 2^(−age/h): the weight left after `age` ticks (1 for age 0).
    #[inline]
    pub fn factor(&self, age: u32) -> f32 {
        if age == 0 {
            return 1.0;
        }
        let x = -(age as f32) / self.half_life;
        if !(x > -126.0) {
            return 0.0;
        }
        crate::f32math::exp2(x)
    }
}

impl<const D: usize> ObsStats<D> {
    /// Every observation's weight multiplied by `factor` (in [0, 1]): n and S scale, m stays.
    #[inline]
    pub fn decay(&mut self, factor: f32) {
        self.count *= factor;
        for s in &mut self.scatter {
            *s *= factor;
        }
    }
}

/// A voxel's statistics with the tick of their last change.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Stamped<const D: usize> {
    /// (n, m, S) as of `time`.
    pub obs: ObsStats<D>,
    /// Tick of the last change.
    pub time: u32,
}

impl<const D: usize> Stamped<D> {
    /// Nothing observed, stamped at tick 0.
    pub const EMPTY: Self = Self {
        obs: ObsStats::EMPTY,
        time: 0,
    };

    /// The statistics as seen at tick `now` (undecayed for a stamp at or after `now`).
    #[inline]
    pub fn at(&self, forgetting: &Forgetting, now: u32) -> ObsStats<D> {
        let mut obs = self.obs;
        obs.decay(forgetting.factor(now.saturating_sub(self.time)));
        obs
    }

    /// Bring the statistics forward to tick `now` (no-op for `now` ≤ stamp).
    #[inline]
    pub fn advance(&mut self, forgetting: &Forgetting, now: u32) {
        if now > self.time {
            self.obs.decay(forgetting.factor(now - self.time));
            self.time = now;
        }
    }

    /// One point observed at tick `now`.
    #[inline]
    pub fn add_point(&mut self, forgetting: &Forgetting, now: u32, y: &[f32; D]) {
        self.advance(forgetting, now);
        self.obs.add_point(y);
    }

    /// Merge another stamped set (another robot's, or an evicted residency): both at the later stamp.
    pub fn merge(&mut self, forgetting: &Forgetting, other: &Self) {
        let now = self.time.max(other.time);
        self.advance(forgetting, now);
        let mut o = other.obs;
        o.decay(forgetting.factor(now - other.time));
        self.obs.merge(&o);
    }
}

/// How a map keeps time. [`Timeless`] never forgets and stores nothing: its stamp is `()`, so a map of it
/// has the paper's layout and code (a firmware that does not forget links none of this). [`Fading`] keeps a
/// `u32` tick per voxel and forgets when given a half-life.
pub trait MapClock: Copy + core::fmt::Debug {
    /// What a voxel keeps of the time of its last change.
    type Stamp: Copy + core::fmt::Debug + PartialEq;
    /// The clock of an unconfigured map (forgetting off, tick 0).
    const OFF: Self;
    /// The stamp of tick 0.
    const ZERO: Self::Stamp;
    /// How the map forgets now (`None`: it does not).
    fn forgetting(&self) -> Option<Forgetting>;
    /// Forget with `forgetting` from now on; `false` if this clock cannot (a [`Timeless`] map).
    fn set_forgetting(&mut self, forgetting: Option<Forgetting>) -> bool;
    /// The stamp of a change made now.
    fn now(&self) -> Self::Stamp;
    /// Move the clock to tick `now` (never backwards: an earlier tick is ignored).
    fn set_time(&mut self, now: u32);
    /// A stamp as a tick of the mission clock (0 for a timeless map).
    fn tick(stamp: Self::Stamp) -> u32;
}

/// The clock of a map that never forgets: nothing stored, nothing computed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Timeless;

impl MapClock for Timeless {
    type Stamp = ();
    const OFF: Self = Self;
    const ZERO: () = ();
    #[inline(always)]
    fn forgetting(&self) -> Option<Forgetting> {
        None
    }
    fn set_forgetting(&mut self, forgetting: Option<Forgetting>) -> bool {
        forgetting.is_none()
    }
    #[inline(always)]
    fn now(&self) {}
    #[inline(always)]
    fn set_time(&mut self, _now: u32) {}
    #[inline(always)]
    fn tick(_stamp: ()) -> u32 {
        0
    }
}

/// The clock of a map that can forget: the mission tick and the half-life (off until set).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Fading {
    forgetting: Option<Forgetting>,
    now: u32,
}

impl MapClock for Fading {
    type Stamp = u32;
    const OFF: Self = Self {
        forgetting: None,
        now: 0,
    };
    const ZERO: u32 = 0;
    #[inline]
    fn forgetting(&self) -> Option<Forgetting> {
        self.forgetting
    }
    fn set_forgetting(&mut self, forgetting: Option<Forgetting>) -> bool {
        self.forgetting = forgetting;
        true
    }
    #[inline]
    fn now(&self) -> u32 {
        self.now
    }
    fn set_time(&mut self, now: u32) {
        self.now = self.now.max(now);
    }
    #[inline]
    fn tick(stamp: u32) -> u32 {
        stamp
    }
}

/// `obs`, stamped `from`, brought forward to `to` under `clock` (unchanged when the clock does not forget
/// or `to` is not later).
#[inline]
pub fn bring_forward<C: MapClock, const D: usize>(
    clock: &C,
    obs: &mut ObsStats<D>,
    from: C::Stamp,
    to: C::Stamp,
) {
    if let Some(f) = clock.forgetting() {
        let age = C::tick(to).saturating_sub(C::tick(from));
        if age > 0 {
            obs.decay(f.factor(age));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// (tick, feature) observations; the f64 weighted moments at tick `now`.
    fn reference(points: &[(u32, [f32; 2])], h: f64, now: u32) -> (f64, [f64; 2], [f64; 2]) {
        let w = |t: u32| libm::exp2(-f64::from(now - t) / h);
        let n: f64 = points.iter().map(|(t, _)| w(*t)).sum();
        let m: [f64; 2] = core::array::from_fn(|d| {
            points
                .iter()
                .map(|(t, y)| w(*t) * f64::from(y[d]))
                .sum::<f64>()
                / n
        });
        let s: [f64; 2] = core::array::from_fn(|d| {
            points
                .iter()
                .map(|(t, y)| w(*t) * (f64::from(y[d]) - m[d]).powi(2))
                .sum()
        });
        (n, m, s)
    }

    fn assert_close(got: &ObsStats<2>, want: &(f64, [f64; 2], [f64; 2])) {
        assert!((f64::from(got.count) - want.0).abs() < 1e-5 * want.0);
        for d in 0..2 {
            assert!((f64::from(got.mean[d]) - want.1[d]).abs() < 1e-5);
            assert!((f64::from(got.scatter[d]) - want.2[d]).abs() < 1e-4 * want.2[d].max(1.0));
        }
    }

    const POINTS: [(u32, [f32; 2]); 8] = [
        (0, [1.0, 0.0]),
        (0, [0.8, 0.1]),
        (3, [0.9, -0.2]),
        (10, [-1.0, 1.0]),
        (10, [-0.8, 0.9]),
        (17, [-1.1, 1.2]),
        (25, [0.0, 0.5]),
        (40, [-0.9, 1.0]),
    ];

    #[test]
    fn lazy_decay_equals_the_weighted_moments() {
        let f = Forgetting::new(8.0).unwrap();
        let mut v = Stamped::<2>::EMPTY;
        for (t, y) in POINTS {
            v.add_point(&f, t, &y);
        }
        for now in [40, 41, 64, 200] {
            assert_close(&v.at(&f, now), &reference(&POINTS, 8.0, now));
        }
    }

    #[test]
    fn merges_of_stamped_sets_are_exact_in_any_order() {
        // Two robots see alternate points; a base station merges their voxels in either order, and a
        // third set arrives late with an older stamp.
        let f = Forgetting::new(5.0).unwrap();
        let (mut a, mut b, mut c) = (Stamped::<2>::EMPTY, Stamped::EMPTY, Stamped::EMPTY);
        for (i, (t, y)) in POINTS.iter().enumerate() {
            match i % 3 {
                0 => a.add_point(&f, *t, y),
                1 => b.add_point(&f, *t, y),
                _ => c.add_point(&f, *t, y),
            }
        }
        let want = reference(&POINTS, 5.0, 50);
        let mut ab = a;
        ab.merge(&f, &b);
        ab.merge(&f, &c);
        let mut cb = c;
        cb.merge(&f, &b);
        cb.merge(&f, &a);
        assert_eq!(ab.time, 40);
        assert_eq!(cb.time, 40);
        assert_close(&ab.at(&f, 50), &want);
        assert_close(&cb.at(&f, 50), &want);
    }

    #[test]
    fn the_factor_halves_per_half_life_and_never_grows() {
        let f = Forgetting::new(10.0).unwrap();
        assert_eq!(f.factor(0), 1.0);
        assert!((f.factor(10) - 0.5).abs() < 1e-6);
        assert!((f.factor(30) - 0.125).abs() < 1e-6);
        assert_eq!(f.factor(u32::MAX), 0.0);
        let mut v = Stamped::<2> {
            obs: ObsStats {
                count: 4.0,
                mean: [1.0, 2.0],
                scatter: [1.0, 1.0],
            },
            time: 20,
        };
        // A reader behind the stamp sees it undecayed; advancing backwards does nothing.
        assert_eq!(v.at(&f, 5).count, 4.0);
        v.advance(&f, 5);
        assert_eq!(v.time, 20);
        assert_eq!(v.at(&f, 30).mean, [1.0, 2.0], "the mean does not fade");
        assert!(Forgetting::new(0.0).is_none() && Forgetting::new(f32::NAN).is_none());
        assert!(Forgetting::OFF.is_none());
    }
}
