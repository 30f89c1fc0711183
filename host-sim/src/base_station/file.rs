//! The global map on disk: a versioned, checksummed, exact file.
//!
//! The base station runs for days and must survive restarts, so the map is saved whole — settled
//! observation statistics, closed contribution ids (so copies arriving after a restart are still ignored) and live
//! contributions — with every f32 bit-exact: save → load gives an identical map and identical query
//! results. A truncated, corrupted or foreign file is refused with an error that says which.
//!
//! Layout (little-endian):
//!
//! ```text
//! magic        8 bytes  "LBKIGMAP"
//! version      u32      FILE_VERSION
//! config_len   u32      then the session configuration, postcard-encoded (wire format)
//! voxels       u64
//! per voxel (sorted by key):
//!   key        3 × i32
//!   settled    n f32, m D × f32, S D × f32
//!   closed     u32 count, then (robot u16, session u32, residency u32) each
//!   live       u32 count, then (robot u16, session u32, residency u32, seq u32, n, m, S) each
//! crc32        u32      CRC-32 (ISO-HDLC) of every byte before it
//! ```

use super::global_map::{ContributionId, GlobalMap, GlobalVoxel, LiveContribution};
use latentbki::wire::{SessionConfig, CRC32};
use latentbki::{ObsStats, VoxelKey};
use std::path::Path;

/// File magic.
pub const MAGIC: &[u8; 8] = b"LBKIGMAP";
/// Current file format version.
pub const FILE_VERSION: u32 = 2;

/// Why a map file could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// Reading failed.
    // The OS error is in the message, so it is not chained as a `source` too (anyhow would print it twice).
    #[error("cannot read {path}: {error}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        error: std::io::Error,
    },
    /// The file does not start with the map magic.
    #[error("not a latentbki global map file (expected magic \"LBKIGMAP\")")]
    NotAMap,
    /// A format version this build does not read.
    #[error("map file version {0} is not supported (this build reads version {FILE_VERSION})")]
    UnsupportedVersion(u32),
    /// The file ends early.
    #[error("map file truncated: needed {needed} bytes at offset {at}, file has {len}")]
    Truncated {
        /// Offset of the field.
        at: usize,
        /// Bytes the field needs.
        needed: usize,
        /// File length.
        len: usize,
    },
    /// The checksum does not match (corrupted file).
    #[error("map file checksum mismatch (stored {stored:#010x}, computed {computed:#010x}): the file is corrupted")]
    Checksum {
        /// Stored CRC.
        stored: u32,
        /// Computed CRC.
        computed: u32,
    },
    /// Parsed but inconsistent.
    #[error("map file invalid: {0}")]
    Invalid(String),
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], LoadError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(LoadError::Truncated {
                at: self.at,
                needed: n,
                len: self.bytes.len(),
            });
        };
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn arr<const N: usize>(&mut self) -> Result<[u8; N], LoadError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }
    fn u16(&mut self) -> Result<u16, LoadError> {
        Ok(u16::from_le_bytes(self.arr()?))
    }
    fn u32(&mut self) -> Result<u32, LoadError> {
        Ok(u32::from_le_bytes(self.arr()?))
    }
    fn i32(&mut self) -> Result<i32, LoadError> {
        Ok(i32::from_le_bytes(self.arr()?))
    }
    fn f32(&mut self) -> Result<f32, LoadError> {
        Ok(f32::from_le_bytes(self.arr()?))
    }
    fn stats<const D: usize>(&mut self) -> Result<ObsStats<D>, LoadError> {
        let count = self.f32()?;
        let mut s = ObsStats {
            count,
            ..ObsStats::EMPTY
        };
        for m in s.mean.iter_mut() {
            *m = self.f32()?;
        }
        for p in s.scatter.iter_mut() {
            *p = self.f32()?;
        }
        if !s.is_valid() {
            return Err(LoadError::Invalid(
                "a voxel's statistics are not finite or negative".into(),
            ));
        }
        Ok(s)
    }
    fn id(&mut self) -> Result<ContributionId, LoadError> {
        Ok(ContributionId {
            robot: self.u16()?,
            session: self.u32()?,
            residency: self.u32()?,
        })
    }
    /// A count whose items need at least `item` bytes each: refuse counts the file cannot hold.
    fn count(&mut self, item: usize) -> Result<usize, LoadError> {
        let n = self.u32()? as usize;
        let left = self.bytes.len() - self.at;
        if n.saturating_mul(item) > left {
            return Err(LoadError::Truncated {
                at: self.at,
                needed: n.saturating_mul(item),
                len: self.bytes.len(),
            });
        }
        Ok(n)
    }
}

fn put_stats<const D: usize>(out: &mut Vec<u8>, s: &ObsStats<D>) {
    out.extend_from_slice(&s.count.to_le_bytes());
    for v in s.mean.iter().chain(&s.scatter) {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

fn put_id(out: &mut Vec<u8>, id: &ContributionId) {
    out.extend_from_slice(&id.robot.to_le_bytes());
    out.extend_from_slice(&id.session.to_le_bytes());
    out.extend_from_slice(&id.residency.to_le_bytes());
}

impl<const D: usize> GlobalMap<D> {
    /// The map as file bytes (deterministic: voxels and contributions sorted).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&FILE_VERSION.to_le_bytes());
        let mut cfg = [0u8; 64];
        let cfg =
            postcard::to_slice(self.config(), &mut cfg).expect("a session config is < 64 bytes");
        out.extend_from_slice(&(cfg.len() as u32).to_le_bytes());
        out.extend_from_slice(cfg);
        let keys = self.sorted_keys();
        out.extend_from_slice(&(keys.len() as u64).to_le_bytes());
        for k in keys {
            let v = self.voxel(&k).expect("key from the map");
            for c in k.as_array() {
                out.extend_from_slice(&c.to_le_bytes());
            }
            put_stats(&mut out, &v.settled);
            let mut closed = v.closed.clone();
            closed.sort();
            out.extend_from_slice(&(closed.len() as u32).to_le_bytes());
            for id in &closed {
                put_id(&mut out, id);
            }
            let mut live = v.live.clone();
            live.sort_by_key(|c| c.id);
            out.extend_from_slice(&(live.len() as u32).to_le_bytes());
            for c in &live {
                put_id(&mut out, &c.id);
                out.extend_from_slice(&c.seq.to_le_bytes());
                put_stats(&mut out, &c.obs);
            }
        }
        let crc = CRC32.checksum(&out);
        out.extend_from_slice(&crc.to_le_bytes());
        out
    }

    /// Parse file bytes.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, LoadError> {
        if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
            return Err(LoadError::NotAMap);
        }
        let mut r = Reader { bytes, at: 8 };
        let version = r.u32()?;
        if version != FILE_VERSION {
            return Err(LoadError::UnsupportedVersion(version));
        }
        if bytes.len() < 8 + 4 + 4 {
            return Err(LoadError::Truncated {
                at: bytes.len(),
                needed: 4,
                len: bytes.len(),
            });
        }
        let (content, crc) = bytes.split_at(bytes.len() - 4);
        let stored = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
        let computed = CRC32.checksum(content);
        if stored != computed {
            // A file cut short fails here too; say "truncated" when the structure says so.
            let mut probe = Reader {
                bytes: content,
                at: 12,
            };
            if let Err(e @ LoadError::Truncated { .. }) = Self::parse(&mut probe) {
                return Err(e);
            }
            return Err(LoadError::Checksum { stored, computed });
        }
        let mut r = Reader {
            bytes: content,
            at: 12,
        };
        let map = Self::parse(&mut r)?;
        if r.at != content.len() {
            return Err(LoadError::Invalid(format!(
                "{} unexpected bytes after the last voxel",
                content.len() - r.at
            )));
        }
        Ok(map)
    }

    fn parse(r: &mut Reader<'_>) -> Result<Self, LoadError> {
        let n = r.count(1)?;
        let config: SessionConfig = postcard::from_bytes(r.take(n)?)
            .map_err(|e| LoadError::Invalid(format!("session configuration: {e}")))?;
        let mut map = GlobalMap::new(config).map_err(|e| {
            LoadError::Invalid(format!(
                "configuration (D = {}) unusable by this {D}-dimensional build: {e}",
                config.dim
            ))
        })?;
        let voxels = u64::from_le_bytes(r.arr()?);
        let stats_len = 4 + 8 * D;
        let per_voxel = 12 + stats_len + 8;
        if voxels.saturating_mul(per_voxel as u64) > (r.bytes.len() - r.at) as u64 {
            return Err(LoadError::Truncated {
                at: r.at,
                needed: voxels.saturating_mul(per_voxel as u64) as usize,
                len: r.bytes.len(),
            });
        }
        let mut previous: Option<VoxelKey> = None;
        for _ in 0..voxels {
            let key = VoxelKey::new(r.i32()?, r.i32()?, r.i32()?);
            if !key.in_range() || previous.is_some_and(|p| p >= key) {
                return Err(LoadError::Invalid(format!(
                    "voxel key {key:?} out of range or out of order"
                )));
            }
            previous = Some(key);
            let settled = r.stats()?;
            let n = r.count(10)?;
            let mut closed = Vec::with_capacity(n);
            for _ in 0..n {
                closed.push(r.id()?);
            }
            let n = r.count(14 + stats_len)?;
            let mut live = Vec::with_capacity(n);
            for _ in 0..n {
                let id = r.id()?;
                let seq = r.u32()?;
                live.push(LiveContribution {
                    id,
                    seq,
                    obs: r.stats()?,
                });
            }
            map.insert_raw(
                key,
                GlobalVoxel {
                    settled,
                    closed,
                    live,
                },
            );
        }
        Ok(map)
    }

    /// Write the map to a file (atomically: a temporary file, then rename).
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        let tmp = path.with_extension("tmp");
        std::fs::write(&tmp, self.to_bytes())?;
        std::fs::rename(&tmp, path)
    }

    /// Read a map file.
    pub fn load(path: &Path) -> Result<Self, LoadError> {
        let bytes = std::fs::read(path).map_err(|error| LoadError::Io {
            path: path.display().to_string(),
            error,
        })?;
        Self::from_bytes(&bytes)
    }
}
