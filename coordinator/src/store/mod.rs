//! The durable queue: jobs, their finished frames and strips, per-worker
//! records and the id counter, in a database — SQLite embedded in the
//! state folder (WAL mode) by default, PostgreSQL for a farm that keeps
//! its data on a server — through one query layer (`sqlx`'s `Any`), so
//! both run the same statements. Images are files in the state folder,
//! indexed here. A coordinator killed at any moment restarts from what is
//! written here: a job before its submission is acknowledged, a change of
//! state before watchers hear of it, frames and strips as they arrive.

mod schema;

use crate::job_state::JobState;
use anyhow::Context;
use sqlx::any::{AnyPoolOptions, AnyRow};
use sqlx::{AnyPool, Connection, Row};

/// A job as the database keeps it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct JobRow {
    /// Its id, `job-PREFIX-SEQ`.
    pub id: String,
    /// Submission order.
    pub seq: u64,
    /// Where it is in its life.
    pub state: Option<JobState>,
    /// Higher runs first.
    pub priority: i32,
    /// The client's name for it.
    pub name: String,
    /// Who submitted it.
    pub submitter: String,
    /// The job spec as the client sent it (protobuf).
    pub spec: Vec<u8>,
    /// The scene bundle's hash (the bundle is a file of the state folder).
    pub bundle_hash: String,
    /// Frames (1 unless a sequence).
    pub frames: u32,
    /// Frames stored.
    pub frames_done: u32,
    /// Strips rendered.
    pub strips_done: u32,
    /// Strips planned.
    pub strips_total: u32,
    /// Strips rendered again after a failure.
    pub retries: u32,
    /// Why it failed.
    pub error: String,
    /// Its figures, once done.
    pub stats_json: String,
    /// When it was submitted, started and ended, ms since the Unix epoch.
    pub submitted_ms: u64,
    /// When it started (0: not yet).
    pub started_ms: u64,
    /// When it ended (0: not yet).
    pub finished_ms: u64,
    /// Bytes its results take (or are reserved for, until it ends).
    pub result_bytes: u64,
}

/// A finished frame's files, relative to the state folder.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameRow {
    /// Frame number, from 0.
    pub frame: u32,
    /// The linear HDR frame.
    pub exr: String,
    /// The tone-mapped frame ("" until the job's exposure is known).
    pub png: String,
    /// Bytes of both files.
    pub bytes: u64,
    /// The frame's figures.
    pub stats_json: String,
    /// BLAKE3 of the EXR file, hex: checked when it is served.
    pub exr_hash: String,
    /// BLAKE3 of the PNG file, hex ("" until it is written).
    pub png_hash: String,
}

/// A strip of an unfinished frame, kept so a restart does not render it again.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StripRow {
    /// Frame number.
    pub frame: u32,
    /// First column.
    pub x0: u32,
    /// Column after the last.
    pub x1: u32,
    /// Who rendered it.
    pub worker: String,
    /// The worker's reply as received, relative to the state folder.
    pub path: String,
}

/// What the farm has seen of one worker.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WorkerRow {
    /// `host:port`.
    pub addr: String,
    /// Strips it rendered.
    pub strips_done: u64,
    /// Strips that failed on it.
    pub strips_failed: u64,
    /// When it last registered or answered, ms since the Unix epoch.
    pub last_seen_ms: u64,
}

/// A user's token as the database keeps it: never the token, its hash.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct TokenRow {
    /// The token's public id (its second part).
    pub id: String,
    /// Whose it is.
    pub user: String,
    /// `admin`, `submitter` or `worker`.
    pub role: String,
    /// BLAKE3 of its secret part, hex.
    #[serde(skip)]
    pub hash: String,
    /// When it was made, ms since the Unix epoch.
    pub created_ms: u64,
    /// When it was revoked (0: it is not).
    pub revoked_ms: u64,
}

/// One entry of the audit log.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct AuditRow {
    /// Its number, in order.
    pub id: u64,
    /// When, ms since the Unix epoch.
    pub at_ms: u64,
    /// Who: a user, `operator` (the command line on the state folder) or `worker`.
    pub actor: String,
    /// What: `submit`, `cancel`, `priority`, `token add`, …
    pub action: String,
    /// What to: a job id, a token id, a worker's address.
    pub target: String,
    /// More, in words.
    pub detail: String,
}

/// Whether the database takes writes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Health {
    /// Since when writes fail, ms since the Unix epoch (0: they do not).
    pub failing_since_ms: u64,
    /// Writes that failed since then.
    pub failed_writes: u64,
    /// The last failure, in words.
    pub error: String,
}

impl Health {
    /// Whether the last write went through.
    pub fn ok(&self) -> bool {
        self.failing_since_ms == 0
    }
}

impl AuditRow {
    /// An entry made now (its number is given when it is written).
    pub fn now(actor: &str, action: &str, target: &str, detail: &str) -> AuditRow {
        AuditRow {
            id: 0,
            at_ms: now_ms() as u64,
            actor: actor.into(),
            action: action.into(),
            target: target.into(),
            detail: detail.into(),
        }
    }
}

/// The database.
#[derive(Clone, Debug)]
pub struct Store {
    pool: AnyPool,
    postgres: bool,
    /// Whether its last write went through, and since when it has not.
    health: std::sync::Arc<std::sync::Mutex<Health>>,
    /// On PostgreSQL, the connection holding this coordinator's advisory
    /// lock on the database for the process's life.
    _holder: Option<std::sync::Arc<tokio::sync::Mutex<sqlx::AnyConnection>>>,
    /// On SQLite, the lock file beside the database a coordinator holds.
    _file_lock: Option<std::sync::Arc<std::fs::File>>,
    /// What the database was before this process opened it.
    found: Found,
}

/// What a database was when it was opened.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Found {
    /// A Sylva database (it has a schema).
    Existing,
    /// Nothing: no file, or a server database without Sylva's tables.
    New,
    /// An SQLite file of 0 bytes: a database truncated or lost, not a new one.
    EmptyFile,
}

/// The advisory lock one coordinator holds on a PostgreSQL database.
const COORDINATOR_LOCK: i64 = 0x5379_6c76_6100_0001;

/// The file an `sqlite:` URL names (none for an in-memory database).
fn sqlite_path(url: &str) -> Option<std::path::PathBuf> {
    let rest = url.strip_prefix("sqlite://").or_else(|| url.strip_prefix("sqlite:"))?;
    let path = rest.split('?').next().unwrap_or("");
    (!path.is_empty() && path != ":memory:").then(|| path.into())
}

/// Locks `PATH.lock` beside an SQLite database for this process: refused
/// while another coordinator holds it, whatever its state folder.
fn lock_beside(db: &std::path::Path, url: &str) -> anyhow::Result<std::fs::File> {
    let mut name = db.as_os_str().to_owned();
    name.push(".lock");
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&name)
        .with_context(|| format!("cannot lock the database {}", redacted(url)))?;
    file.try_lock().map_err(|_| {
        anyhow::anyhow!(
            "another coordinator is using the database {}: one coordinator per database",
            redacted(url)
        )
    })?;
    Ok(file)
}

/// A database URL without its password, for messages.
pub fn redacted(url: &str) -> String {
    match (url.find("://"), url.rfind('@')) {
        (Some(s), Some(at)) if at > s => format!("{}://…@{}", &url[..s], &url[at + 1..]),
        _ => url.to_string(),
    }
}

impl Store {
    /// Opens (creating if need be) the database at `url` — `sqlite://PATH`
    /// or `postgres://…` — and brings its schema up to date: for a tool
    /// beside the coordinator (`sylva token`, `sylva audit`).
    pub async fn open(url: &str) -> anyhow::Result<Store> {
        Self::connect(url, false).await
    }

    /// Opens the database as its coordinator: refused while another
    /// coordinator holds it (on PostgreSQL, by an advisory lock held for
    /// this process's life; on SQLite, by a lock on `PATH.lock` beside the
    /// file, whichever state folder each coordinator has). Its schema is
    /// left as found, so the caller can check [`Store::found`] first; then
    /// [`Store::migrate`].
    pub async fn claim(url: &str) -> anyhow::Result<Store> {
        Self::connect(url, true).await
    }

    /// What the database was before this process opened it.
    pub fn found(&self) -> Found {
        self.found
    }

    async fn connect(url: &str, exclusive: bool) -> anyhow::Result<Store> {
        // Two processes opening a new SQLite file at once (a `sylva token`
        // beside a starting coordinator) can find it locked while the other
        // sets it up: such a refusal is waited out, briefly.
        let mut tries = 0;
        loop {
            match Self::connect_once(url, exclusive).await {
                Err(e) if tries < 50 && format!("{e:#}").contains("database is locked") => {
                    tries += 1;
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                }
                r => return r,
            }
        }
    }

    async fn connect_once(url: &str, exclusive: bool) -> anyhow::Result<Store> {
        sqlx::any::install_default_drivers();
        let postgres = url.starts_with("postgres://") || url.starts_with("postgresql://");
        let sqlite = url.starts_with("sqlite:");
        anyhow::ensure!(
            postgres || sqlite,
            "database {}: sqlite://PATH or postgres://USER@HOST/DB",
            redacted(url)
        );
        let path = sqlite_path(url);
        let file_lock = match &path {
            Some(p) if exclusive => Some(std::sync::Arc::new(lock_beside(p, url)?)),
            _ => None,
        };
        let empty_file =
            path.as_ref().and_then(|p| std::fs::metadata(p).ok()).is_some_and(|m| m.len() == 0);
        let url = if sqlite && !url.contains('?') { format!("{url}?mode=rwc") } else { url.into() };
        // SQLite takes one writer at a time: one connection serialises the
        // coordinator's writes rather than failing them as "locked".
        let pool = AnyPoolOptions::new()
            .max_connections(if sqlite { 1 } else { 4 })
            .connect(&url)
            .await
            .with_context(|| format!("cannot open the database {}", redacted(&url)))?;
        // One coordinator per database: two would both run its queue.
        // (SQLite's file is in the state folder, which is locked already.)
        let holder = if postgres && exclusive {
            use sqlx::Connection;
            let mut c = sqlx::AnyConnection::connect(&url).await?;
            let got: bool = sqlx::query("SELECT pg_try_advisory_lock($1)")
                .bind(COORDINATOR_LOCK)
                .fetch_one(&mut c)
                .await?
                .try_get(0)?;
            anyhow::ensure!(
                got,
                "another coordinator is using the database {}: one coordinator per database",
                redacted(&url)
            );
            Some(std::sync::Arc::new(tokio::sync::Mutex::new(c)))
        } else {
            None
        };
        let has_schema: i64 = sqlx::query(if postgres {
            "SELECT COUNT(*) FROM information_schema.tables WHERE table_name = 'schema_migrations'"
        } else {
            "SELECT COUNT(*) FROM sqlite_master WHERE type = 'table' AND name = 'schema_migrations'"
        })
        .fetch_one(&pool)
        .await?
        .try_get(0)?;
        let found = match (has_schema > 0, empty_file) {
            (true, _) => Found::Existing,
            (false, true) => Found::EmptyFile,
            (false, false) => Found::New,
        };
        let store = Store {
            pool,
            postgres,
            health: Default::default(),
            _holder: holder,
            _file_lock: file_lock,
            found,
        };
        if !exclusive {
            store.migrate().await?;
        }
        Ok(store)
    }

    /// Which database this is, in words.
    pub fn kind(&self) -> &'static str {
        if self.postgres { "PostgreSQL" } else { "SQLite" }
    }

    /// Brings the schema up to date (a tool's [`Store::open`] does so itself).
    pub async fn migrate(&self) -> anyhow::Result<()> {
        if !self.postgres {
            // Readers never block the writer, and a commit is one append.
            // (Set here, not on opening: a file found wanting is left as found.)
            sqlx::query("PRAGMA journal_mode = WAL").execute(&self.pool).await?;
        }
        sqlx::query(
            "CREATE TABLE IF NOT EXISTS schema_migrations (
                version BIGINT PRIMARY KEY, name TEXT NOT NULL, applied_ms BIGINT NOT NULL)",
        )
        .execute(&self.pool)
        .await?;
        let applied: Vec<i64> = sqlx::query("SELECT version FROM schema_migrations")
            .fetch_all(&self.pool)
            .await?
            .iter()
            .map(|r| r.get::<i64, _>(0))
            .collect();
        let newest = schema::MIGRATIONS.last().map_or(0, |m| m.0);
        if let Some(v) = applied.iter().find(|v| **v > newest) {
            anyhow::bail!(
                "the database is at schema version {v}, newer than this coordinator's {newest}: \
                 run the newer coordinator, or another database"
            );
        }
        for (version, name, statements) in schema::MIGRATIONS {
            if applied.contains(version) {
                continue;
            }
            match self.apply(*version, name, statements).await {
                Ok(()) => tracing::info!(version, name, "database schema migrated"),
                // Another process (a `sylva token` beside a starting
                // coordinator) applied it at the same moment: its
                // transaction won, and the schema is as it should be.
                Err(_) if self.has_migration(*version).await? => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// Applies one migration and records it, in one transaction.
    async fn apply(&self, version: i64, name: &str, statements: &[&str]) -> anyhow::Result<()> {
        let mut tx = self.pool.begin().await?;
        for s in statements {
            sqlx::query(&schema::in_dialect(s, self.postgres))
                .execute(&mut *tx)
                .await
                .with_context(|| format!("schema migration {version} ({name})"))?;
        }
        sqlx::query(
            "INSERT INTO schema_migrations (version, name, applied_ms) VALUES ($1, $2, $3)",
        )
        .bind(version)
        .bind(name)
        .bind(now_ms())
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(())
    }

    /// Whether migration `version` is recorded as applied.
    async fn has_migration(&self, version: i64) -> anyhow::Result<bool> {
        let r = sqlx::query("SELECT COUNT(*) FROM schema_migrations WHERE version = $1")
            .bind(version)
            .fetch_one(&self.pool)
            .await?;
        Ok(r.try_get::<i64, _>(0)? > 0)
    }

    /// Runs `f` on a connection of its own (`write`: whether a failure
    /// makes the store unhealthy); an error closes that
    /// connection, so whatever the failure left behind (SQLite may end a
    /// transaction itself on a full disk, and the driver's count of open
    /// transactions then disagrees with the file's) dies with it, and the
    /// next call starts clean. Nothing acknowledged after a failure can
    /// sit in a transaction that never commits.
    async fn with<T>(
        &self,
        write: bool,
        f: impl AsyncFnOnce(&mut sqlx::AnyConnection) -> sqlx::Result<T>,
    ) -> anyhow::Result<T> {
        let mut c = match self.pool.acquire().await {
            Ok(c) => c,
            Err(e) => return Err(self.failed(write, e.into())),
        };
        match f(&mut c).await {
            Ok(v) => Ok(v),
            Err(e) => {
                c.close_on_drop();
                Err(self.failed(write, e.into()))
            }
        }
    }

    /// Records a failed call; a failed write makes the store unhealthy.
    fn failed(&self, write: bool, e: anyhow::Error) -> anyhow::Error {
        if write {
            let mut h = sylva_proto::sync::lock(&self.health);
            if h.failing_since_ms == 0 {
                h.failing_since_ms = now_ms() as u64;
                tracing::error!(
                    "the database cannot be written: {e:#}; jobs go on from memory, \
                     submissions are refused, and what failed is written again when it can be"
                );
            }
            h.failed_writes += 1;
            h.error = format!("{e:#}");
        }
        e
    }

    /// After failed writes, tries one (the time of the last write, kept
    /// in `meta`): when it goes through, the store is healthy again. The
    /// caller asks once everything owed is written, so one small write
    /// that squeezes onto a nearly full disk does not end the episode.
    pub async fn probe(&self) -> bool {
        if self.health().ok() {
            return true;
        }
        let at = now_ms().to_string();
        let r = self
            .with(true, async |c| {
                sqlx::query(
                    "INSERT INTO meta (key, value) VALUES ('last_write_ms', $1)
                     ON CONFLICT (key) DO UPDATE SET value = excluded.value",
                )
                .bind(&at)
                .execute(&mut *c)
                .await
                .map(drop)
            })
            .await;
        if r.is_err() {
            return false;
        }
        let mut h = sylva_proto::sync::lock(&self.health);
        tracing::warn!(
            failed_writes = h.failed_writes,
            "the database takes writes again, after {} s",
            (now_ms() as u64).saturating_sub(h.failing_since_ms) / 1000
        );
        *h = Health::default();
        true
    }

    /// Whether the last write went through, and if not, why and since when.
    pub fn health(&self) -> Health {
        sylva_proto::sync::lock(&self.health).clone()
    }

    /// A value kept under `key`, set to `make()` the first time it is asked for.
    pub async fn meta(&self, key: &str, make: impl FnOnce() -> String) -> anyhow::Result<String> {
        let value = make();
        self.with(true, async |c| {
            sqlx::query(
                "INSERT INTO meta (key, value) VALUES ($1, $2) ON CONFLICT (key) DO NOTHING",
            )
            .bind(key)
            .bind(value)
            .execute(&mut *c)
            .await?;
            sqlx::query("SELECT value FROM meta WHERE key = $1")
                .bind(key)
                .fetch_one(&mut *c)
                .await?
                .try_get::<String, _>(0)
        })
        .await
    }

    /// The next job number: never one handed out before, by any
    /// coordinator on this database.
    pub async fn next_seq(&self) -> anyhow::Result<u64> {
        self.with(true, async |c| {
            let r = sqlx::query(
                "UPDATE counters SET value = value + 1 WHERE name = 'job' RETURNING value",
            )
            .fetch_one(&mut *c)
            .await?;
            Ok(r.try_get::<i64, _>(0)? as u64)
        })
        .await
    }

    /// Records a new job.
    pub async fn insert_job(&self, j: &JobRow) -> anyhow::Result<()> {
        self.with(true, async |c| {
            sqlx::query(
                "INSERT INTO jobs (id, seq, state, priority, name, submitter, spec, bundle_hash,
                    frames, submitted_ms, result_bytes)
                 VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11)",
            )
            .bind(&j.id)
            .bind(j.seq as i64)
            .bind(j.state.map_or("queued", JobState::name))
            .bind(j.priority as i64)
            .bind(&j.name)
            .bind(&j.submitter)
            .bind(j.spec.clone())
            .bind(&j.bundle_hash)
            .bind(j.frames as i64)
            .bind(j.submitted_ms as i64)
            .bind(j.result_bytes as i64)
            .execute(&mut *c)
            .await
            .map(drop)
        })
        .await
    }

    /// Every job, in submission order.
    pub async fn jobs(&self) -> anyhow::Result<Vec<JobRow>> {
        let rows = self
            .with(false, async |c| {
                sqlx::query("SELECT * FROM jobs ORDER BY seq").fetch_all(&mut *c).await
            })
            .await?;
        rows.iter().map(job_row).collect()
    }

    /// A job's state, and with it the reason it failed and when it started or ended.
    pub async fn set_state(&self, j: &JobRow) -> anyhow::Result<()> {
        self.with(true, async |c| {
            sqlx::query(
                "UPDATE jobs SET state = $2, error = $3, started_ms = $4, finished_ms = $5
                 WHERE id = $1",
            )
            .bind(&j.id)
            .bind(j.state.map_or("queued", JobState::name))
            .bind(&j.error)
            .bind(j.started_ms as i64)
            .bind(j.finished_ms as i64)
            .execute(&mut *c)
            .await
            .map(drop)
        })
        .await
    }

    /// A job's progress counts.
    pub async fn set_progress(&self, j: &JobRow) -> anyhow::Result<()> {
        self.with(true, async |c| {
            sqlx::query(
                "UPDATE jobs SET strips_done = $2, strips_total = $3, frames_done = $4, retries = $5
                 WHERE id = $1",
            )
            .bind(&j.id)
            .bind(j.strips_done as i64)
            .bind(j.strips_total as i64)
            .bind(j.frames_done as i64)
            .bind(j.retries as i64)
            .execute(&mut *c)
            .await
            .map(drop)
        })
        .await
    }

    /// A job's priority.
    pub async fn set_priority(&self, id: &str, priority: i32) -> anyhow::Result<()> {
        self.with(true, async |c| {
            sqlx::query("UPDATE jobs SET priority = $2 WHERE id = $1")
                .bind(id)
                .bind(priority as i64)
                .execute(&mut *c)
                .await
                .map(drop)
        })
        .await
    }

    /// A finished job's figures and the bytes its results take.
    pub async fn set_stats(&self, id: &str, stats_json: &str, bytes: u64) -> anyhow::Result<()> {
        self.with(true, async |c| {
            sqlx::query("UPDATE jobs SET stats_json = $2, result_bytes = $3 WHERE id = $1")
                .bind(id)
                .bind(stats_json)
                .bind(bytes as i64)
                .execute(&mut *c)
                .await
                .map(drop)
        })
        .await
    }

    /// Forgets a job, its frames and strips (its files are the caller's).
    pub async fn delete_job(&self, id: &str) -> anyhow::Result<()> {
        self.with(true, async |c| {
            let mut tx = c.begin().await?;
            for table in ["strips", "frames", "jobs"] {
                let key = if table == "jobs" { "id" } else { "job_id" };
                sqlx::query(&format!("DELETE FROM {table} WHERE {key} = $1"))
                    .bind(id)
                    .execute(&mut *tx)
                    .await?;
            }
            tx.commit().await
        })
        .await
    }

    /// Bytes that results take or are reserved for, over every job kept.
    pub async fn result_bytes(&self) -> anyhow::Result<u64> {
        self.with(false, async |c| {
            let r = sqlx::query("SELECT CAST(COALESCE(SUM(result_bytes), 0) AS BIGINT) FROM jobs")
                .fetch_one(&mut *c)
                .await?;
            Ok(r.try_get::<i64, _>(0).unwrap_or(0).max(0) as u64)
        })
        .await
    }

    /// Records a finished frame (replacing an earlier record of it), and
    /// drops the strips it was put together from.
    pub async fn put_frame(&self, id: &str, f: &FrameRow) -> anyhow::Result<()> {
        self.with(true, async |c| {
            let mut tx = c.begin().await?;
            sqlx::query(
                "INSERT INTO frames (job_id, frame, exr, png, bytes, stats_json, exr_hash, png_hash)
                 VALUES ($1, $2, $3, $4, $5, $6, $7, $8)
                 ON CONFLICT (job_id, frame) DO UPDATE SET exr = excluded.exr, png = excluded.png,
                    bytes = excluded.bytes, stats_json = excluded.stats_json,
                    exr_hash = excluded.exr_hash, png_hash = excluded.png_hash",
            )
            .bind(id)
            .bind(f.frame as i64)
            .bind(&f.exr)
            .bind(&f.png)
            .bind(f.bytes as i64)
            .bind(&f.stats_json)
            .bind(&f.exr_hash)
            .bind(&f.png_hash)
            .execute(&mut *tx)
            .await?;
            sqlx::query("DELETE FROM strips WHERE job_id = $1 AND frame = $2")
                .bind(id)
                .bind(f.frame as i64)
                .execute(&mut *tx)
                .await?;
            tx.commit().await
        })
        .await
    }

    /// A job's finished frames, in order.
    pub async fn frames(&self, id: &str) -> anyhow::Result<Vec<FrameRow>> {
        let rows = self
            .with(false, async |c| {
                sqlx::query("SELECT * FROM frames WHERE job_id = $1 ORDER BY frame")
                    .bind(id)
                    .fetch_all(&mut *c)
                    .await
            })
            .await?;
        rows.iter()
            .map(|r| {
                Ok(FrameRow {
                    frame: r.try_get::<i64, _>("frame")? as u32,
                    exr: r.try_get("exr")?,
                    png: r.try_get("png")?,
                    bytes: r.try_get::<i64, _>("bytes")? as u64,
                    stats_json: r.try_get("stats_json")?,
                    exr_hash: r.try_get("exr_hash")?,
                    png_hash: r.try_get("png_hash")?,
                })
            })
            .collect()
    }

    /// Records a strip of an unfinished frame.
    pub async fn put_strip(&self, id: &str, s: &StripRow) -> anyhow::Result<()> {
        self.with(true, async |c| {
            sqlx::query(
                "INSERT INTO strips (job_id, frame, x0, x1, worker, path)
                 VALUES ($1, $2, $3, $4, $5, $6)
                 ON CONFLICT (job_id, frame, x0) DO UPDATE SET x1 = excluded.x1,
                    worker = excluded.worker, path = excluded.path",
            )
            .bind(id)
            .bind(s.frame as i64)
            .bind(s.x0 as i64)
            .bind(s.x1 as i64)
            .bind(&s.worker)
            .bind(&s.path)
            .execute(&mut *c)
            .await
            .map(drop)
        })
        .await
    }

    /// The strips kept of a job's unfinished frames.
    pub async fn strips(&self, id: &str) -> anyhow::Result<Vec<StripRow>> {
        let rows = self
            .with(false, async |c| {
                sqlx::query("SELECT * FROM strips WHERE job_id = $1 ORDER BY frame, x0")
                    .bind(id)
                    .fetch_all(&mut *c)
                    .await
            })
            .await?;
        rows.iter()
            .map(|r| {
                Ok(StripRow {
                    frame: r.try_get::<i64, _>("frame")? as u32,
                    x0: r.try_get::<i64, _>("x0")? as u32,
                    x1: r.try_get::<i64, _>("x1")? as u32,
                    worker: r.try_get("worker")?,
                    path: r.try_get("path")?,
                })
            })
            .collect()
    }

    /// Records what the farm has seen of each of `workers`.
    pub async fn put_workers(&self, workers: &[WorkerRow]) -> anyhow::Result<()> {
        self.with(true, async |c| {
            let mut tx = c.begin().await?;
            for w in workers {
                sqlx::query(
                    "INSERT INTO workers (addr, strips_done, strips_failed, last_seen_ms)
                     VALUES ($1, $2, $3, $4)
                     ON CONFLICT (addr) DO UPDATE SET strips_done = excluded.strips_done,
                        strips_failed = excluded.strips_failed,
                        last_seen_ms = excluded.last_seen_ms",
                )
                .bind(&w.addr)
                .bind(w.strips_done as i64)
                .bind(w.strips_failed as i64)
                .bind(w.last_seen_ms as i64)
                .execute(&mut *tx)
                .await?;
            }
            tx.commit().await
        })
        .await
    }

    /// Forgets a worker's record.
    pub async fn delete_worker(&self, addr: &str) -> anyhow::Result<()> {
        self.with(true, async |c| {
            sqlx::query("DELETE FROM workers WHERE addr = $1")
                .bind(addr)
                .execute(&mut *c)
                .await
                .map(drop)
        })
        .await
    }

    /// Every worker's record.
    pub async fn workers(&self) -> anyhow::Result<Vec<WorkerRow>> {
        let rows = self
            .with(false, async |c| {
                sqlx::query("SELECT * FROM workers ORDER BY addr").fetch_all(&mut *c).await
            })
            .await?;
        rows.iter()
            .map(|r| {
                Ok(WorkerRow {
                    addr: r.try_get("addr")?,
                    strips_done: r.try_get::<i64, _>("strips_done")? as u64,
                    strips_failed: r.try_get::<i64, _>("strips_failed")? as u64,
                    last_seen_ms: r.try_get::<i64, _>("last_seen_ms")? as u64,
                })
            })
            .collect()
    }

    /// Records a user's token (its hash: the token itself is never kept).
    /// Refused when the user exists with another role: ownership is by
    /// name, so one name with two roles would share one user's jobs.
    pub async fn add_token(&self, t: &TokenRow) -> anyhow::Result<()> {
        let other = self
            .tokens()
            .await?
            .into_iter()
            .find(|o| o.user == t.user && o.role != t.role && o.revoked_ms == 0);
        if let Some(o) = other {
            anyhow::bail!(
                "user {:?} already has a {} token ({}): one user, one role; pick another name, \
                 or revoke that token first",
                t.user,
                o.role,
                o.id
            );
        }
        self.with(true, async |c| {
            sqlx::query(
                "INSERT INTO tokens (id, user_name, role, hash, created_ms)
                 VALUES ($1, $2, $3, $4, $5)",
            )
            .bind(&t.id)
            .bind(&t.user)
            .bind(&t.role)
            .bind(&t.hash)
            .bind(t.created_ms as i64)
            .execute(&mut *c)
            .await
            .map(drop)
        })
        .await
    }

    /// Every token record, revoked ones too, oldest first.
    pub async fn tokens(&self) -> anyhow::Result<Vec<TokenRow>> {
        let rows = self
            .with(false, async |c| {
                sqlx::query("SELECT * FROM tokens ORDER BY created_ms, id").fetch_all(&mut *c).await
            })
            .await?;
        rows.iter()
            .map(|r| {
                Ok(TokenRow {
                    id: r.try_get("id")?,
                    user: r.try_get("user_name")?,
                    role: r.try_get("role")?,
                    hash: r.try_get("hash")?,
                    created_ms: r.try_get::<i64, _>("created_ms")?.max(0) as u64,
                    revoked_ms: r.try_get::<i64, _>("revoked_ms")?.max(0) as u64,
                })
            })
            .collect()
    }

    /// Revokes a token; whether there was one to revoke.
    pub async fn revoke_token(&self, id: &str) -> anyhow::Result<bool> {
        self.with(true, async |c| {
            let r =
                sqlx::query("UPDATE tokens SET revoked_ms = $2 WHERE id = $1 AND revoked_ms = 0")
                    .bind(id)
                    .bind(now_ms())
                    .execute(&mut *c)
                    .await?;
            Ok(r.rows_affected() > 0)
        })
        .await
    }

    /// Appends to the audit log: who did what to what, and when (ms since
    /// the Unix epoch: an entry written late keeps its time).
    pub async fn audit(&self, e: &AuditRow) -> anyhow::Result<()> {
        self.with(true, async |c| {
            let mut tx = c.begin().await?;
            let id = sqlx::query(
                "UPDATE counters SET value = value + 1 WHERE name = 'audit' RETURNING value",
            )
            .fetch_one(&mut *tx)
            .await?
            .try_get::<i64, _>(0)?;
            sqlx::query(
                "INSERT INTO audit (id, at_ms, actor, action, target, detail)
                 VALUES ($1, $2, $3, $4, $5, $6)",
            )
            .bind(id)
            .bind(e.at_ms as i64)
            .bind(&e.actor)
            .bind(&e.action)
            .bind(&e.target)
            .bind(&e.detail)
            .execute(&mut *tx)
            .await?;
            tx.commit().await
        })
        .await
    }

    /// The newest `limit` entries of the audit log, oldest first.
    pub async fn audit_log(&self, limit: u32) -> anyhow::Result<Vec<AuditRow>> {
        let rows = self
            .with(false, async |c| {
                sqlx::query("SELECT * FROM audit ORDER BY id DESC LIMIT $1")
                    .bind(limit as i64)
                    .fetch_all(&mut *c)
                    .await
            })
            .await?;
        let mut out = rows
            .iter()
            .map(|r| {
                Ok(AuditRow {
                    id: r.try_get::<i64, _>("id")? as u64,
                    at_ms: r.try_get::<i64, _>("at_ms")?.max(0) as u64,
                    actor: r.try_get("actor")?,
                    action: r.try_get("action")?,
                    target: r.try_get("target")?,
                    detail: r.try_get("detail")?,
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        out.reverse();
        Ok(out)
    }

    /// Closes the connections, waiting for writes under way.
    pub async fn close(&self) {
        self.pool.close().await;
    }
}

fn job_row(r: &AnyRow) -> anyhow::Result<JobRow> {
    let n = |c: &str| r.try_get::<i64, _>(c).map(|v| v.max(0) as u64);
    let state: String = r.try_get("state")?;
    Ok(JobRow {
        id: r.try_get("id")?,
        seq: n("seq")?,
        state: Some(
            JobState::from_name(&state).with_context(|| {
                format!("a job in the database is in an unknown state {state:?}")
            })?,
        ),
        priority: r.try_get::<i64, _>("priority")? as i32,
        name: r.try_get("name")?,
        submitter: r.try_get("submitter")?,
        spec: r.try_get("spec")?,
        bundle_hash: r.try_get("bundle_hash")?,
        frames: n("frames")? as u32,
        frames_done: n("frames_done")? as u32,
        strips_done: n("strips_done")? as u32,
        strips_total: n("strips_total")? as u32,
        retries: n("retries")? as u32,
        error: r.try_get("error")?,
        stats_json: r.try_get("stats_json")?,
        submitted_ms: n("submitted_ms")?,
        started_ms: n("started_ms")?,
        finished_ms: n("finished_ms")?,
        result_bytes: n("result_bytes")?,
    })
}

/// Milliseconds since the Unix epoch.
pub fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_job_and_its_frames_outlive_the_connection() {
        let dir = std::env::temp_dir().join(format!("sylva-store-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let url = format!("sqlite://{}", dir.join("sylva.db").display());
        let s = Store::open(&url).await.unwrap();
        let prefix = s.meta("prefix", || "abcd".into()).await.unwrap();
        assert_eq!((s.next_seq().await.unwrap(), s.next_seq().await.unwrap()), (1, 2));
        let job = JobRow {
            id: "job-abcd-1".into(),
            seq: 1,
            state: Some(JobState::Queued),
            priority: -3,
            name: "n".into(),
            submitter: "me".into(),
            spec: vec![0, 1, 255],
            bundle_hash: "h".into(),
            frames: 24,
            submitted_ms: 7,
            result_bytes: 1000,
            ..Default::default()
        };
        s.insert_job(&job).await.unwrap();
        let strip = StripRow { frame: 3, x0: 0, x1: 8, worker: "w:1".into(), path: "p".into() };
        s.put_strip(&job.id, &strip).await.unwrap();
        let f = FrameRow { frame: 2, exr: "a.exr".into(), bytes: 9, ..Default::default() };
        s.put_frame(&job.id, &f).await.unwrap();
        let running = JobRow { state: Some(JobState::Running), started_ms: 8, ..job.clone() };
        s.set_state(&running).await.unwrap();
        s.put_workers(&[WorkerRow { addr: "w:1".into(), strips_done: 5, ..Default::default() }])
            .await
            .unwrap();
        s.close().await;
        // Opened again (the migrations already applied), everything is there.
        let s = Store::open(&url).await.unwrap();
        assert_eq!(s.meta("prefix", || "other".into()).await.unwrap(), prefix);
        assert_eq!(s.next_seq().await.unwrap(), 3, "a number is never handed out twice");
        assert_eq!(s.jobs().await.unwrap(), vec![running]);
        assert_eq!(s.frames(&job.id).await.unwrap(), vec![f.clone()]);
        assert_eq!(s.strips(&job.id).await.unwrap(), vec![strip]);
        assert_eq!(s.workers().await.unwrap()[0].strips_done, 5);
        assert_eq!(s.result_bytes().await.unwrap(), 1000);
        // A frame put together drops its strips.
        s.put_frame(&job.id, &FrameRow { frame: 3, ..f }).await.unwrap();
        assert!(s.strips(&job.id).await.unwrap().is_empty());
        s.delete_job(&job.id).await.unwrap();
        assert!(s.jobs().await.unwrap().is_empty() && s.frames(&job.id).await.unwrap().is_empty());
        s.close().await;
        std::fs::remove_dir_all(&dir).ok();
    }

    #[tokio::test]
    async fn two_processes_opening_a_new_database_at_once_both_get_its_schema() {
        let dir = std::env::temp_dir().join(format!("sylva-store-race-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let url = format!("sqlite://{}", dir.join("sylva.db").display());
        for _ in 0..5 {
            std::fs::remove_file(dir.join("sylva.db")).ok();
            let (a, b, c) = tokio::join!(Store::open(&url), Store::open(&url), Store::claim(&url));
            let c = c.unwrap();
            c.migrate().await.unwrap();
            for s in [a.unwrap(), b.unwrap(), c] {
                assert!(s.jobs().await.unwrap().is_empty());
                s.close().await;
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_url_loses_its_password_in_messages() {
        assert_eq!(redacted("postgres://sylva:secret@db:5432/farm"), "postgres://…@db:5432/farm");
        assert_eq!(redacted("sqlite:///var/lib/sylva.db"), "sqlite:///var/lib/sylva.db");
    }
}
