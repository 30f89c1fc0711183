//! Where the global map lives between runs: a small storage trait and its SQLite implementation.
//!
//! The base station keeps its working set in memory ([`super::GlobalMap`]) and hands the storage, at a
//! bounded interval, everything that changed since the last commit: the voxels touched (opaque, versioned
//! records from [`super::GlobalVoxel::to_record`]) and the sequence state of the sessions whose frames
//! touched them. One [`MapStore::commit`] is one transaction, so a frame's summaries and the sequence state
//! that marks it merged become durable together, or not at all: after any crash a restart merges every
//! frame exactly once and counts the frames of the lost window as lost.
//!
//! The store only sees keys and byte records, so a change of what a voxel holds touches its serializer, not
//! this module, and a larger engine can take over by implementing the trait (the README sketches sharding by
//! voxel-block key). [`SqliteStore`] is the embedded default: one file, WAL journal (readers never block
//! the receiver and always see one committed snapshot), `synchronous = FULL` (a commit survives a power cut).

use latentbki::key::VoxelKey;
use rusqlite::{params, Connection, OpenFlags, OptionalExtension};
use std::path::{Path, PathBuf};

/// Version of the database layout (tables and what their records mean). Bump it with any change.
pub const SCHEMA_VERSION: u32 = 1;
/// SQLite's `application_id` for latentbki map databases ("LBKI").
const APPLICATION_ID: i32 = 0x4c42_4b49;

/// Everything a store holds, as one consistent snapshot.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Snapshot {
    /// The feature dimension the map was created with (None: the store is new and empty).
    pub dim: Option<u32>,
    /// The sessions' configuration, postcard-encoded (None until the first session header).
    pub config: Option<Vec<u8>>,
    /// Voxel records by key.
    pub voxels: Vec<(VoxelKey, Vec<u8>)>,
    /// Session records by `(robot, session)`.
    pub sessions: Vec<((u16, u32), Vec<u8>)>,
    /// Unix time of the last commit in milliseconds (0: never).
    pub committed_at_ms: u64,
}

/// What changed since the last commit; written in one transaction.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Changes {
    /// Feature dimension and configuration, when the map adopted one.
    pub config: Option<(u32, Vec<u8>)>,
    /// Voxel records to insert or replace.
    pub voxels: Vec<(VoxelKey, Vec<u8>)>,
    /// Session records to insert or replace.
    pub sessions: Vec<((u16, u32), Vec<u8>)>,
}

impl Changes {
    /// Whether there is nothing to write.
    pub fn is_empty(&self) -> bool {
        self.config.is_none() && self.voxels.is_empty() && self.sessions.is_empty()
    }
}

/// Why the store failed.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// SQLite said no (I/O, locking, a file that is not a database).
    #[error("{path}: {error}")]
    Sqlite {
        /// The database file.
        path: String,
        /// SQLite's error.
        error: rusqlite::Error,
    },
    /// A SQLite database, but not a latentbki map.
    #[error("{0}: not a latentbki map database")]
    NotAMap(String),
    /// A map database of another layout version.
    #[error("{path}: map database schema version {found} is not supported (this build reads version {SCHEMA_VERSION}); export it with the build that wrote it")]
    Version {
        /// The database file.
        path: String,
        /// Its version.
        found: u32,
    },
    /// A read-only open of a database that does not exist.
    #[error("{0}: no such map database")]
    Missing(String),
    /// Another receiver has the database open for writing (two working sets would overwrite each other).
    #[error("{0}: another base station is writing this map database")]
    InUse(String),
    /// The receiver's lock file could not be opened.
    #[error("{path}: cannot open the lock file: {error}")]
    Lock {
        /// The lock file.
        path: String,
        /// The cause.
        error: std::io::Error,
    },
}

/// Storage of the global map: whole snapshots out, atomic change sets in.
pub trait MapStore {
    /// Everything stored, as of one commit.
    fn snapshot(&mut self) -> Result<Snapshot, StoreError>;
    /// Write these changes atomically (all or nothing) and durably.
    fn commit(&mut self, changes: &Changes) -> Result<(), StoreError>;
}

/// The map in one SQLite file.
pub struct SqliteStore {
    conn: Connection,
    path: PathBuf,
    /// The receiver's exclusive lock (`<db>-receiver.lock`), held while open for writing: one writer per
    /// database, any number of readers.
    _lock: Option<std::fs::File>,
}

const SCHEMA: &str = "
CREATE TABLE schema_version (version INTEGER NOT NULL);
CREATE TABLE meta (name TEXT PRIMARY KEY, value BLOB NOT NULL) WITHOUT ROWID;
CREATE TABLE voxels (
    x INTEGER NOT NULL, y INTEGER NOT NULL, z INTEGER NOT NULL,
    record BLOB NOT NULL,
    PRIMARY KEY (x, y, z)
) WITHOUT ROWID;
CREATE TABLE sessions (
    robot INTEGER NOT NULL, session INTEGER NOT NULL,
    record BLOB NOT NULL,
    PRIMARY KEY (robot, session)
) WITHOUT ROWID;
";

/// How long [`SqliteStore::open`] waits for a receiver's lock that another holder may be about to release.
///
/// Why wait at all: the lock is an `flock` on the lock file, held by every open copy of its descriptor. A
/// process that starts a child (`fork`, `posix_spawn`) gives the child a copy of every descriptor until the
/// child's `exec` closes them (`O_CLOEXEC`), so for that moment a closed store's lock is still held — by a
/// child of another thread of the same program. A base station that reopens its database while another
/// thread spawns a process (a test suite, a supervisor) saw "another base station is writing" for a lock
/// no receiver held (CI, `stream_db`, under load). A receiver that really holds the lock holds it for
/// longer than this, and is reported after it.
const LOCK_WAIT: std::time::Duration = std::time::Duration::from_secs(1);

/// Take `file`'s exclusive lock, trying again for up to `wait` while another holder has it: `Ok(false)` if
/// it is still held then.
fn lock_within(file: &std::fs::File, wait: std::time::Duration) -> std::io::Result<bool> {
    let start = std::time::Instant::now();
    loop {
        match file.try_lock() {
            Ok(()) => return Ok(true),
            Err(std::fs::TryLockError::WouldBlock) if start.elapsed() < wait => {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            Err(std::fs::TryLockError::WouldBlock) => return Ok(false),
            Err(std::fs::TryLockError::Error(error)) => return Err(error),
        }
    }
}

impl SqliteStore {
    /// Open the database for the receiver (created if missing), checking its schema version.
    pub fn open(path: &Path) -> Result<Self, StoreError> {
        let lock = if path.as_os_str() == ":memory:" {
            None
        } else {
            let mut lock_path = path.as_os_str().to_owned();
            lock_path.push("-receiver.lock");
            let file = std::fs::OpenOptions::new()
                .create(true)
                .truncate(false)
                .write(true)
                .open(&lock_path)
                .map_err(|error| StoreError::Lock {
                    path: PathBuf::from(&lock_path).display().to_string(),
                    error,
                })?;
            match lock_within(&file, LOCK_WAIT) {
                Ok(true) => Some(file),
                Ok(false) => return Err(StoreError::InUse(path.display().to_string())),
                Err(error) => {
                    return Err(StoreError::Lock {
                        path: PathBuf::from(&lock_path).display().to_string(),
                        error,
                    })
                }
            }
        };
        let conn = Connection::open(path).map_err(sqlite(path))?;
        let mut store = Self {
            conn,
            path: path.to_path_buf(),
            _lock: lock,
        };
        store.init().map_err(|e| store.err(e))??;
        Ok(store)
    }

    /// Open an existing database read-only (for queries and exports while a receiver writes it).
    pub fn open_read_only(path: &Path) -> Result<Self, StoreError> {
        if !path.exists() {
            return Err(StoreError::Missing(path.display().to_string()));
        }
        let conn = Connection::open_with_flags(
            path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(sqlite(path))?;
        let store = Self {
            conn,
            path: path.to_path_buf(),
            _lock: None,
        };
        store
            .conn
            .busy_timeout(std::time::Duration::from_secs(10))
            .map_err(|e| store.err(e))?;
        store.check_version().map_err(|e| store.err(e))??;
        Ok(store)
    }

    /// The database file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// `PRAGMA integrity_check`: "ok" for a sound file.
    pub fn integrity_check(&self) -> Result<String, StoreError> {
        self.conn
            .query_row("PRAGMA integrity_check", [], |r| r.get(0))
            .map_err(|e| self.err(e))
    }

    fn err(&self, error: rusqlite::Error) -> StoreError {
        StoreError::Sqlite {
            path: self.path.display().to_string(),
            error,
        }
    }

    /// Set the connection up; create the tables in a new file. Outer error: SQLite; inner: the file's.
    fn init(&mut self) -> rusqlite::Result<Result<(), StoreError>> {
        self.conn.busy_timeout(std::time::Duration::from_secs(10))?;
        // Fails with "file is not a database" on a foreign file: the first read of the header.
        let tables: i64 = self.conn.query_row(
            "SELECT count(*) FROM sqlite_master WHERE type = 'table'",
            [],
            |r| r.get(0),
        )?;
        if tables == 0 {
            let tx = self.conn.transaction()?;
            tx.pragma_update(None, "application_id", APPLICATION_ID)?;
            tx.execute_batch(SCHEMA)?;
            tx.execute(
                "INSERT INTO schema_version (version) VALUES (?1)",
                [SCHEMA_VERSION],
            )?;
            tx.commit()?;
        }
        if let Err(e) = self.check_version()? {
            return Ok(Err(e));
        }
        // WAL persists in the file; synchronous is per connection.
        let _: String = self
            .conn
            .query_row("PRAGMA journal_mode = WAL", [], |r| r.get(0))?;
        self.conn.pragma_update(None, "synchronous", "FULL")?;
        Ok(Ok(()))
    }

    fn check_version(&self) -> rusqlite::Result<Result<(), StoreError>> {
        let name = || self.path.display().to_string();
        let app: i32 = self
            .conn
            .query_row("PRAGMA application_id", [], |r| r.get(0))?;
        if app != APPLICATION_ID {
            return Ok(Err(StoreError::NotAMap(name())));
        }
        let found: Option<u32> = self
            .conn
            .query_row("SELECT version FROM schema_version", [], |r| r.get(0))
            .optional()?;
        Ok(match found {
            Some(SCHEMA_VERSION) => Ok(()),
            Some(found) => Err(StoreError::Version {
                path: name(),
                found,
            }),
            None => Err(StoreError::NotAMap(name())),
        })
    }

    fn read(&mut self) -> rusqlite::Result<Snapshot> {
        // One read transaction: every table as of the same commit.
        let tx = self.conn.transaction()?;
        let meta = |name: &str| -> rusqlite::Result<Option<Vec<u8>>> {
            tx.query_row("SELECT value FROM meta WHERE name = ?1", [name], |r| {
                r.get(0)
            })
            .optional()
        };
        let dim = meta("dim")?.and_then(|b| Some(u32::from_le_bytes(b.try_into().ok()?)));
        let config = meta("config")?;
        let committed_at_ms = meta("committed_at_ms")?
            .and_then(|b| Some(u64::from_le_bytes(b.try_into().ok()?)))
            .unwrap_or(0);
        let voxels = {
            let mut st = tx.prepare("SELECT x, y, z, record FROM voxels")?;
            let rows = st.query_map([], |r| {
                Ok((VoxelKey::new(r.get(0)?, r.get(1)?, r.get(2)?), r.get(3)?))
            })?;
            rows.collect::<rusqlite::Result<Vec<_>>>()?
        };
        let sessions = {
            let mut st = tx.prepare("SELECT robot, session, record FROM sessions")?;
            let rows = st.query_map([], |r| Ok(((r.get(0)?, r.get(1)?), r.get(2)?)))?;
            rows.collect::<rusqlite::Result<Vec<_>>>()?
        };
        tx.finish()?;
        Ok(Snapshot {
            dim,
            config,
            voxels,
            sessions,
            committed_at_ms,
        })
    }

    fn write(&mut self, changes: &Changes) -> rusqlite::Result<()> {
        let tx = self.conn.transaction()?;
        {
            let mut meta =
                tx.prepare_cached("INSERT OR REPLACE INTO meta (name, value) VALUES (?1, ?2)")?;
            if let Some((dim, config)) = &changes.config {
                meta.execute(params!["dim", dim.to_le_bytes()])?;
                meta.execute(params!["config", config])?;
            }
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_millis() as u64);
            meta.execute(params!["committed_at_ms", now.to_le_bytes()])?;
            let mut voxel = tx.prepare_cached(
                "INSERT OR REPLACE INTO voxels (x, y, z, record) VALUES (?1, ?2, ?3, ?4)",
            )?;
            for (k, rec) in &changes.voxels {
                voxel.execute(params![k.x, k.y, k.z, rec])?;
            }
            let mut session = tx.prepare_cached(
                "INSERT OR REPLACE INTO sessions (robot, session, record) VALUES (?1, ?2, ?3)",
            )?;
            for ((robot, s), rec) in &changes.sessions {
                session.execute(params![robot, s, rec])?;
            }
        }
        tx.commit()
    }
}

fn sqlite(path: &Path) -> impl Fn(rusqlite::Error) -> StoreError + '_ {
    move |error| StoreError::Sqlite {
        path: path.display().to_string(),
        error,
    }
}

impl MapStore for SqliteStore {
    fn snapshot(&mut self) -> Result<Snapshot, StoreError> {
        self.read().map_err(|e| self.err(e))
    }
    fn commit(&mut self, changes: &Changes) -> Result<(), StoreError> {
        self.write(changes).map_err(|e| self.err(e))
    }
}
