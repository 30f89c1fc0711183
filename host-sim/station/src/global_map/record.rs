//! A global voxel as the map database stores it: an opaque, versioned byte record, every f32 bit-exact,
//! read back into an equal voxel or refused with a reason (older layouts still read). Apart from the map
//! because the layout is the storage's contract, not the merge's.

use super::{ContributionId, GlobalVoxel, LiveContribution, Part};
use latentbki::forget::Forgetting;
use latentbki::obs::ObsStats;

/// Version of [`GlobalVoxel::to_record`]'s layout. Change it (and [`GlobalVoxel::from_record`]) whenever
/// what a voxel stores changes: a database holding another version is refused with a clear error.
pub const VOXEL_RECORD_VERSION: u8 = 4;

/// Why a stored voxel record could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RecordError {
    /// Another record layout.
    #[error("voxel record version {0} is not supported (this build reads version {VOXEL_RECORD_VERSION})")]
    Version(u8),
    /// Too short, too long, or a count that does not fit.
    #[error("voxel record of {len} bytes is malformed for D = {dim}")]
    Malformed {
        /// Record length.
        len: usize,
        /// This build's dimension.
        dim: usize,
    },
    /// A statistic is not finite (or a count or scatter is negative).
    #[error("voxel record holds non-finite or negative statistics")]
    NotFinite,
}

/// Bytes of one serialized [`ObsStats`] (n, m, S as f32).
const fn stats_len(d: usize) -> usize {
    4 + 8 * d
}
/// Bytes of one serialized [`ContributionId`].
const ID_LEN: usize = 10;

impl<const D: usize> GlobalVoxel<D> {
    /// The voxel as an opaque, versioned byte record (the unit the map's storage keeps per key): every f32
    /// bit-exact and every list in id order, so [`GlobalVoxel::from_record`] gives back an equal voxel.
    ///
    /// Layout (little-endian): version u8 (4); base flag u8, then if 1 the base's n, m (D), S (D) as f32 and
    /// its tick u32; closed count u32, then (robot u16, session u32, residency u32) each; parts count u32,
    /// then (id, n, m, S, tick u32) each; live count u32, then (id, seq u32, n, m, S, tick u32) each. The
    /// settled statistics are not stored: they are the fold of base and parts. Versions 2 and 3 (settled
    /// statistics and closed ids only; version 2 without ticks) are still read: their settled statistics
    /// become the base.
    pub fn to_record(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(
            2 + stats_len(D)
                + 4
                + 12
                + ID_LEN * self.closed.len()
                + (ID_LEN + 4 + stats_len(D)) * self.parts.len()
                + (ID_LEN + 8 + stats_len(D)) * self.live.len(),
        );
        out.push(VOXEL_RECORD_VERSION);
        if self.base == ObsStats::EMPTY && self.base_time == 0 {
            out.push(0);
        } else {
            out.push(1);
            put_stats(&mut out, &self.base);
            out.extend_from_slice(&self.base_time.to_le_bytes());
        }
        out.extend_from_slice(&(self.closed.len() as u32).to_le_bytes());
        for id in &self.closed {
            put_id(&mut out, id);
        }
        out.extend_from_slice(&(self.parts.len() as u32).to_le_bytes());
        for p in &self.parts {
            put_id(&mut out, &p.id);
            put_stats(&mut out, &p.obs);
            out.extend_from_slice(&p.time.to_le_bytes());
        }
        out.extend_from_slice(&(self.live.len() as u32).to_le_bytes());
        for c in &self.live {
            put_id(&mut out, &c.id);
            out.extend_from_slice(&c.seq.to_le_bytes());
            put_stats(&mut out, &c.obs);
            out.extend_from_slice(&c.time.to_le_bytes());
        }
        out
    }

    /// Read a record written by [`GlobalVoxel::to_record`] (or by a build of version 2 or 3); refuse any
    /// other version, length, order or a non-finite value. `forgetting` is the map's (the fold needs it).
    pub fn from_record(bytes: &[u8], forgetting: Option<&Forgetting>) -> Result<Self, RecordError> {
        let malformed = RecordError::Malformed {
            len: bytes.len(),
            dim: D,
        };
        let (&version, rest) = bytes.split_first().ok_or(malformed.clone())?;
        if !(2..=VOXEL_RECORD_VERSION).contains(&version) {
            return Err(RecordError::Version(version));
        }
        let ticks = version >= 3;
        let tick = |r: &mut Cursor<'_>| if ticks { r.u32() } else { Some(0) };
        let mut r = Cursor(rest);
        let parse = |r: &mut Cursor<'_>| -> Option<Result<Self, RecordError>> {
            let (base, base_time) = if version >= 4 {
                match r.arr::<1>()? {
                    [0] => (ObsStats::EMPTY, 0),
                    [1] => (r.stats::<D>()?, r.u32()?),
                    _ => return None,
                }
            } else {
                (r.stats::<D>()?, tick(r)?)
            };
            let n = r.count(ID_LEN)?;
            let mut closed = Vec::with_capacity(n);
            for _ in 0..n {
                closed.push(r.id()?);
            }
            let mut parts = Vec::new();
            if version >= 4 {
                let n = r.count(ID_LEN + 4 + stats_len(D))?;
                parts.reserve(n);
                for _ in 0..n {
                    let id = r.id()?;
                    let obs = r.stats::<D>()?;
                    parts.push(Part {
                        id,
                        obs,
                        time: r.u32()?,
                    });
                }
            }
            let n = r.count(ID_LEN + 4 + 4 * usize::from(ticks) + stats_len(D))?;
            let mut live = Vec::with_capacity(n);
            for _ in 0..n {
                let id = r.id()?;
                let seq = r.u32()?;
                let obs = r.stats::<D>()?;
                live.push(LiveContribution {
                    id,
                    seq,
                    obs,
                    time: tick(r)?,
                });
            }
            if !r.0.is_empty() {
                return None;
            }
            live.sort_by_key(|c: &LiveContribution<D>| c.id);
            closed.sort_unstable();
            // Parts are written in id order, each one closed: anything else is not this layout.
            let sorted = parts.windows(2).all(|w| w[0].id < w[1].id)
                && parts.iter().all(|p| closed.binary_search(&p.id).is_ok());
            if !sorted {
                return None;
            }
            let finite = base.is_valid()
                && parts.iter().all(|p| p.obs.is_valid())
                && live.iter().all(|c| c.obs.is_valid());
            Some(if finite {
                let mut v = GlobalVoxel {
                    settled: ObsStats::EMPTY,
                    settled_time: 0,
                    closed,
                    parts,
                    base,
                    base_time,
                    live,
                };
                v.refold(forgetting);
                Ok(v)
            } else {
                Err(RecordError::NotFinite)
            })
        };
        parse(&mut r).unwrap_or(Err(malformed))
    }
}

pub(super) fn put_stats<const D: usize>(out: &mut Vec<u8>, s: &ObsStats<D>) {
    out.extend_from_slice(&s.count.to_le_bytes());
    for v in s.mean.iter().chain(&s.scatter) {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

pub(super) fn put_id(out: &mut Vec<u8>, id: &ContributionId) {
    out.extend_from_slice(&id.robot.to_le_bytes());
    out.extend_from_slice(&id.session.to_le_bytes());
    out.extend_from_slice(&id.residency.to_le_bytes());
}

/// Reads a record front to back; `None` when it ends early.
struct Cursor<'a>(&'a [u8]);

impl Cursor<'_> {
    fn arr<const N: usize>(&mut self) -> Option<[u8; N]> {
        let (head, rest) = self.0.split_first_chunk::<N>()?;
        self.0 = rest;
        Some(*head)
    }
    fn u32(&mut self) -> Option<u32> {
        self.arr().map(u32::from_le_bytes)
    }
    fn f32(&mut self) -> Option<f32> {
        self.arr().map(f32::from_le_bytes)
    }
    fn id(&mut self) -> Option<ContributionId> {
        Some(ContributionId {
            robot: u16::from_le_bytes(self.arr()?),
            session: self.u32()?,
            residency: self.u32()?,
        })
    }
    fn stats<const D: usize>(&mut self) -> Option<ObsStats<D>> {
        let mut s = ObsStats {
            count: self.f32()?,
            ..ObsStats::EMPTY
        };
        for v in s.mean.iter_mut().chain(s.scatter.iter_mut()) {
            *v = self.f32()?;
        }
        Some(s)
    }
    /// A count of items of at least `item` bytes that the rest can hold.
    fn count(&mut self, item: usize) -> Option<usize> {
        let n = self.u32()? as usize;
        (n.checked_mul(item)? <= self.0.len()).then_some(n)
    }
}
