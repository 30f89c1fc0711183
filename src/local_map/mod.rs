//! The on-device local map: what was observed around the robot, in a fixed pool, no heap, nothing copied.
//!
//! Shape and why:
//! - **Observations, not posteriors.** A voxel stores its own observation statistics (n, m, S)
//!   ([`crate::obs`]): a point updates one voxel, not the f³ its kernel reaches, and a posterior is gathered
//!   from the neighbours' statistics when asked ([`LocalMap::posterior`]). Voxels no point fell in take no
//!   room, yet every voxel within the kernel's reach of a stored one can be answered.
//! - **Hot voxels in f32, the rest quantized.** The `H` most recently observed voxels accumulate points in
//!   f32 (one Welford step per point, no decoding); a voxel is quantized ([`crate::quant`]) only when it
//!   cools down — its hot statistics merge into its codes (Chan's formula, exact) when another voxel needs
//!   the hot entry. A voxel seen over several frames is re-encoded once per visit, not once per batch, and
//!   the rounding error does not grow with the number of batches.
//! - **int8 features** accumulate as exact integer sums and cool by the target's [`crate::quant::Cooling`]: in f32 where
//!   there is an FPU, in fixed point ([`crate::quant::Int8Fix`], no float operation) where there is none.
//! - **Slots** hold the quantized statistics and a key stored as 3 × i16, wrapped around the window centre
//!   (the window is far smaller than 2¹⁶ voxels, so the full key is recovered exactly).
//! - **Index**: open addressing with linear probing over 2·CAP u16 entries (slot + 1, 0 = empty): O(1)
//!   lookup for 4 bytes per voxel; deletion shifts back the few entries of its probe run, so no tombstones.
//!   (A heapless `FnvIndexMap<VoxelKey, u16, N>` costs ~20 B per voxel; see the size test.)
//! - **Ring of slots, CLOCK eviction**: when the pool is full, a hand sweeps the slots like a ring buffer and
//!   evicts the first one not observed since the hand last passed (second chance) — the classic O(1)
//!   approximation of least-recently-observed. Hot voxels are never evicted for room.
//! - **Window**: the map follows the robot; voxels farther than the window radius are evicted in place. A
//!   move reads every key but writes only the evicted slots: nothing is copied.
//! - **Every eviction goes to an [`EvictionSink`](crate::sink::EvictionSink)** with the voxel's observation statistics; if the sink
//!   refuses, the voxel stays and the refusal is counted. Nothing is forgotten silently.
//!
//! The parts live in private submodules: `index` (key → slot), `slots` (the ring, CLOCK eviction, flush),
//! `hot` (the f32 tier and cooling), `window` (wrapped keys, moving the window), `live` (which held voxels
//! changed since the link last streamed them), `int8` (int8 features), `codes` (per-dimension weights of the
//! mean codes), `read` (statistics, posteriors, what it can answer), `intake` (adding f32 points: a point's hot
//! entry); this file holds the layout and configuration.

use crate::batch::RejectionCounts;
use crate::config::{ConfigError, MapConfig, Prior};
use crate::forget::{Forgetting, MapClock, Timeless};
use crate::kernel::KernelLut;
use crate::key::VoxelKey;
use crate::obs::ObsStats;
use crate::quant::{Dither, Int8Fix, QuantVoxel};

/// Hot (f32) voxels by default (`H`): ≈ 17 KiB at D = 64.
pub const HOT_VOXELS: usize = 32;

/// Entries of the recent-hot hint: one per position of a voxel in an 8 × 8 × 4 tile.
const RECENT_HOT: usize = 256;

/// The recent-hot entry of a voxel: its position in an 8 × 8 × 4 tiling of space, so that neighbouring
/// voxels (what a scan visits in turn) never share one.
#[inline(always)]
fn hot_tile(k: VoxelKey) -> usize {
    ((k.x & 7) | (k.y & 7) << 3 | (k.z & 3) << 6) as usize
}

/// `x > 0.0` for a count (never NaN) by its bits, in integer operations alone: the sign bit makes a
/// negative value (and −0) a negative i32, +0 is 0, and a positive f32 is a positive i32. The map tests
/// counts once per cooling and eviction; on an MCU without an FPU the float compare is a soft-float call.
#[inline(always)]
fn positive(x: f32) -> bool {
    (x.to_bits() as i32) > 0
}

/// Largest window radius in voxels: keeps every resident key within the i16 wrap range of the centre.
pub const MAX_WINDOW_VOXELS: i32 = 16_000;

const OCCUPIED: u8 = 1;
const REFERENCED: u8 = 2;
/// Cooled with points the link has not seen as a live update (see `live`).
const CHANGED: u8 = 4;

/// On v6-M in C order, the key and flags first: a window move reads them in every held slot, and v6-M's
/// loads reach 62 bytes past a pointer at most (a key after the 104 bytes of codes cost the scan one more
/// instruction a load: thumbv6m ToF 8,775 → 8,748 instructions a point). Elsewhere the compiler's order
/// (codes first): C order there cost the M4F's ToF 14 instructions a point and riscv32imac's 2.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(all(target_arch = "arm", target_abi = "eabi"), repr(C))]
struct Slot<const D: usize, const P: usize, T: Copy> {
    key: [i16; 3],
    /// 1 + its hot entry, 0 = cold.
    hot: u8,
    flags: u8,
    /// The statistics observed before the voxel last turned hot (its hot entry holds the rest).
    codes: QuantVoxel<D, P>,
    /// Full width, as [`Evicted::residency`] promises: the base station tells contributions of one voxel
    /// apart by it, so a 16-bit number would repeat after 65,536 allocations and a later residency of the
    /// same voxel could be taken for an earlier, closed one and dropped.
    residency: u32,
    /// When `codes` last changed ([`crate::forget`]): `()` in a map that never forgets, so it costs no byte
    /// there.
    stamp: T,
}

impl<const D: usize, const P: usize, T: Copy> Slot<D, P, T> {
    const fn empty(stamp: T) -> Self {
        Self {
            codes: QuantVoxel::EMPTY,
            key: [0; 3],
            hot: 0,
            flags: 0,
            residency: 0,
            stamp,
        }
    }
}

/// A voxel being observed now: its new points in f32, or as exact integer sums of int8 codes.
#[derive(Clone, Copy, Debug)]
struct Hot<const D: usize, T: Copy> {
    acc: hot::Acc<D>,
    key: VoxelKey,
    slot: u16,
    referenced: bool,
    /// The bits of its point count (f32) when it was last streamed as a live update (0: not yet): a hot
    /// voxel has changed since if its count differs — read per tick and cooling, never written per point.
    /// Bits, so that the test is an integer compare on an MCU without an FPU.
    live_sent: u32,
    /// When `acc` last changed (`()` in a map that never forgets).
    stamp: T,
}

impl<const D: usize, T: Copy> Hot<D, T> {
    const fn empty(stamp: T) -> Self {
        Self {
            acc: hot::Acc::Float(ObsStats::EMPTY),
            key: VoxelKey::new(0, 0, 0),
            slot: 0,
            referenced: false,
            live_sent: 0,
            stamp,
        }
    }
}

/// What the map did so far, for logs and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    /// Points integrated, modulo 2³² (wrapping, so differences stay right on a robot that runs for days).
    pub points: u32,
    /// Voxels handed to the sink.
    pub evicted: u32,
    /// Evictions the sink refused (the voxel stayed).
    pub refused: u32,
    /// Slot writes (allocation, cooling, eviction): a window move that copied the map would show here.
    pub slots_written: u32,
    /// Hot voxels cooled into their quantized slot.
    pub cooled: u32,
}

/// A voxel of the map, decoded.
#[derive(Clone, Copy, Debug)]
pub struct LiveVoxel<const D: usize> {
    /// Its key.
    pub key: VoxelKey,
    /// Its observation statistics (quantized part decoded, hot part merged) as of `time`.
    pub obs: ObsStats<D>,
    /// Its residency number (see [`crate::sink::Evicted::residency`]).
    pub residency: u32,
    /// Tick of its last change ([`crate::forget`]; 0 in a map that never forgets): `obs` are as of then,
    /// and a reader decays them to its own tick by the clock rule.
    pub time: u32,
}

/// A fixed-capacity map of `CAP` voxels of dimension `D` holding quantized observation statistics;
/// `P` = [`crate::quant::packed_len`]`(D)`; `H` hot voxels accumulate in f32.
///
/// `C` is how it keeps time ([`crate::forget`]): [`Timeless`] (the default) never forgets and stores no
/// stamp; [`crate::forget::Fading`] keeps the tick of each voxel's last change (4 B more per voxel) and
/// forgets once given a half-life ([`Self::set_forgetting`]).
///
/// Large: place it in a `static` (see [`LocalMap::EMPTY`] and [`LocalMap::configure`]) or a `Box` on a host.
pub struct LocalMap<
    const D: usize,
    const CAP: usize,
    const P: usize,
    const H: usize = HOT_VOXELS,
    C: MapClock = Timeless,
> {
    config: MapConfig,
    lut: KernelLut,
    slots: [Slot<D, P, C::Stamp>; CAP],
    index: [[u16; CAP]; 2],
    len: usize,
    free_hand: usize,
    clock_hand: usize,
    hot: [Hot<D, C::Stamp>; H],
    hot_len: usize,
    hot_hand: usize,
    /// The hot entry the previous point went to (sensors return points in scan order).
    last_hot: usize,
    /// The hot entry a voxel of each 8 × 8 × 4 tile position last went to ([`hot_tile`]): a point whose
    /// voxel is hot but not the previous point's finds its entry here instead of through the index (a
    /// hint, checked against the entry's key: never stale in effect, nothing to invalidate).
    recent_hot: [u8; RECENT_HOT],
    /// Decoding scratch (a 516-byte temporary kept off the device stack).
    scratch: ObsStats<D>,
    centre: VoxelKey,
    /// Whether the last window move left a voxel outside the window (its eviction was refused).
    stranded: bool,
    /// While `stranded`: how far the centre moved (largest axis, voxels; at most 2¹⁵) since a move last
    /// left nothing outside. Every held key lies within radius + drift of the centre on each axis (a voxel
    /// enters only inside the window), so a move whose eviction is refused need not read the keys for one
    /// leaving the wrap range while radius + drift + the move stays below 2¹⁵ (see `window`).
    drift: u16,
    radius: i32,
    /// Scale of int8 features (y = scale · code); 0 = none set (int8 points are refused).
    int8_scale: f32,
    /// The same scale in the integer forms the fixed-point cooling of int8 sums uses.
    int8_fix: Int8Fix,
    /// How int8 sums cool (a hosted build links both methods; bare metal only its target's).
    #[cfg(not(target_os = "none"))]
    cooling: crate::quant::Cooling,
    /// Per-dimension weights of the mean codes (see `codes`).
    mean_weights: codes::Weights,
    dither: Dither,
    next_residency: u32,
    rejections: RejectionCounts,
    counters: Counters,
    /// The mission tick and the half-life (a zero-size nothing in a [`Timeless`] map).
    clock: C,
}

mod codes;
mod hot;
mod index;
mod int8;
mod intake;
mod live;
mod read;
mod slots;
mod window;

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    const TABLE: usize = 2 * CAP;
    const CAP_OK: () = assert!(
        CAP > H && CAP < u16::MAX as usize && H > 0 && H < u8::MAX as usize,
        "CAP must be in H+1..65535 and H in 1..255"
    );

    /// An unconfigured, empty map, for `static` placement; call [`Self::configure`] before use. Every byte
    /// is zero, so a `static` of it is placed in .bss and costs no flash.
    #[allow(clippy::declare_interior_mutable_const)]
    pub const EMPTY: Self = Self {
        config: MapConfig::UNCONFIGURED,
        lut: KernelLut::EMPTY,
        slots: [Slot::empty(C::ZERO); CAP],
        index: [[0; CAP]; 2],
        len: 0,
        free_hand: 0,
        clock_hand: 0,
        hot: [Hot::empty(C::ZERO); H],
        hot_len: 0,
        hot_hand: 0,
        last_hot: 0,
        recent_hot: [0; RECENT_HOT],
        scratch: ObsStats::EMPTY,
        centre: VoxelKey::new(0, 0, 0),
        stranded: false,
        drift: 0,
        radius: 0,
        int8_scale: 0.0,
        int8_fix: Int8Fix::NONE,
        #[cfg(not(target_os = "none"))]
        cooling: crate::quant::Cooling::NATIVE,
        mean_weights: codes::Weights::ONES,
        dither: Dither::UNSEEDED,
        next_residency: 0,
        rejections: RejectionCounts {
            non_finite_position: 0,
            non_finite_feature: 0,
            key_out_of_range: 0,
            no_room: 0,
            outside_window: 0,
            unpaired: 0,
            code_out_of_range: 0,
            feature_scale: 0,
        },
        counters: Counters {
            points: 0,
            evicted: 0,
            refused: 0,
            slots_written: 0,
            cooled: 0,
        },
        clock: C::OFF,
    };

    /// (Re)configure in place: clears the map. `window_radius` is in metres around the robot.
    pub fn configure(&mut self, config: MapConfig, window_radius: f32) -> Result<(), ConfigError> {
        let () = Self::CAP_OK;
        let radius = libm::ceilf(window_radius / config.voxel_size());
        if !(radius >= 1.0 && radius <= MAX_WINDOW_VOXELS as f32) {
            return Err(ConfigError::Window);
        }
        self.lut.rebuild(&config)?;
        if !self.lut.is_voxel_offset() {
            // Per-voxel statistics cannot express the sub-voxel kernel (see `crate::obs`).
            self.lut = KernelLut::EMPTY;
            return Err(ConfigError::SubVoxelOnDevice);
        }
        self.config = config;
        self.dither = Dither::new(0x5EED_1234);
        self.slots
            .iter_mut()
            .for_each(|s| *s = Slot::empty(C::ZERO));
        self.index = [[0; CAP]; 2];
        self.len = 0;
        self.free_hand = 0;
        self.clock_hand = 0;
        self.hot_len = 0;
        self.hot_hand = 0;
        self.last_hot = 0;
        self.radius = radius as i32;
        self.stranded = false;
        self.int8_scale = 0.0;
        self.int8_fix = Int8Fix::NONE;
        self.mean_weights = codes::Weights::ONES;
        self.rejections = RejectionCounts::default();
        self.counters = Counters::default();
        Ok(())
    }

    /// Forget with `forgetting` from now on (`None`: never, the default). Statistics already held fade from
    /// the tick they last changed. Kept by [`Self::configure`]. A [`Timeless`] map refuses anything but
    /// `None` ([`ConfigError::Forgetting`]): it keeps no stamps.
    pub fn set_forgetting(&mut self, forgetting: Option<Forgetting>) -> Result<(), ConfigError> {
        if self.clock.set_forgetting(forgetting) {
            Ok(())
        } else {
            Err(ConfigError::Forgetting)
        }
    }
    /// How the map forgets (`None`: it does not).
    pub fn forgetting(&self) -> Option<Forgetting> {
        self.clock.forgetting()
    }
    /// Set the mission clock ([`crate::forget`]'s clock rule): points from now on are stamped `now` and
    /// reads decay to it. Never backwards (an earlier tick is ignored); nothing in a [`Timeless`] map.
    pub fn set_time(&mut self, now: u32) {
        self.clock.set_time(now);
    }
    /// The mission tick (0 in a [`Timeless`] map).
    pub fn time(&self) -> u32 {
        C::tick(self.clock.now())
    }

    /// The map's configuration.
    pub fn config(&self) -> &MapConfig {
        &self.config
    }
    /// The prior of the posteriors this map gives.
    pub fn prior(&self) -> Prior {
        self.config.prior()
    }
    /// Voxels held (voxels a point fell in).
    pub fn len(&self) -> usize {
        self.len
    }
    /// Whether no voxel is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Voxels it can hold.
    pub const fn capacity(&self) -> usize {
        CAP
    }
    /// Points refused so far, by reason.
    pub fn rejections(&self) -> RejectionCounts {
        self.rejections
    }
    /// Running totals.
    pub fn counters(&self) -> Counters {
        self.counters
    }
    /// Centre of the window (voxel key).
    pub fn centre(&self) -> VoxelKey {
        self.centre
    }
    /// The kernel table the map gathers posteriors with.
    pub fn kernel(&self) -> &KernelLut {
        &self.lut
    }

    /// Bytes one voxel costs: its slot plus its share of the index.
    pub const BYTES_PER_VOXEL: usize =
        core::mem::size_of::<Slot<D, P, C::Stamp>>() + 2 * core::mem::size_of::<u16>();

    /// Bytes one entry of the full-precision (hot) tier costs.
    pub const BYTES_PER_HOT_VOXEL: usize = core::mem::size_of::<Hot<D, C::Stamp>>();

    /// Bytes of everything else: the kernel table, the decoding scratch, hands and counters.
    pub const FIXED_BYTES: usize = core::mem::size_of::<LocalMap<D, 0, P, 0, C>>();

    /// The map's RAM: `CAP` × [`Self::BYTES_PER_VOXEL`] + `H` × [`Self::BYTES_PER_HOT_VOXEL`] +
    /// [`Self::FIXED_BYTES`]. Equals `size_of::<Self>()` on a 32-bit MCU, where every part is a whole
    /// number of 4-byte words; on a 64-bit host a part that ends half-way through an 8-byte word (an odd
    /// `CAP`'s index, an odd number of hot entries of some D) lets the compiler pack small fields there, and
    /// the two can differ by one word (tested).
    pub const RAM_BYTES: usize =
        CAP * Self::BYTES_PER_VOXEL + H * Self::BYTES_PER_HOT_VOXEL + Self::FIXED_BYTES;
}
