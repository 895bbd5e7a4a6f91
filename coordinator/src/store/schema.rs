//! The database's schema as numbered migrations, applied in order once
//! each and recorded in `schema_migrations`. Written once for both
//! databases: the few words that differ (a byte string's type) are filled
//! in per dialect, and every integer is a `BIGINT` (`INTEGER` affinity in
//! SQLite), so one query layer reads both.

/// Migrations, oldest first: (version, what it does, statements).
pub(super) const MIGRATIONS: &[(i64, &str, &[&str])] = &[
    (
        1,
        "jobs, frames, strips, workers, counters",
        &[
            "CREATE TABLE counters (name TEXT PRIMARY KEY, value BIGINT NOT NULL)",
            "INSERT INTO counters (name, value) VALUES ('job', 0)",
            "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
            "CREATE TABLE jobs (
            id TEXT PRIMARY KEY,
            seq BIGINT NOT NULL,
            state TEXT NOT NULL,
            priority BIGINT NOT NULL,
            name TEXT NOT NULL,
            submitter TEXT NOT NULL,
            spec {BYTES} NOT NULL,
            bundle_hash TEXT NOT NULL,
            frames BIGINT NOT NULL,
            frames_done BIGINT NOT NULL DEFAULT 0,
            strips_done BIGINT NOT NULL DEFAULT 0,
            strips_total BIGINT NOT NULL DEFAULT 0,
            retries BIGINT NOT NULL DEFAULT 0,
            error TEXT NOT NULL DEFAULT '',
            stats_json TEXT NOT NULL DEFAULT '',
            submitted_ms BIGINT NOT NULL,
            started_ms BIGINT NOT NULL DEFAULT 0,
            finished_ms BIGINT NOT NULL DEFAULT 0,
            result_bytes BIGINT NOT NULL DEFAULT 0
        )",
            "CREATE INDEX jobs_by_state ON jobs (state)",
            "CREATE TABLE frames (
            job_id TEXT NOT NULL,
            frame BIGINT NOT NULL,
            exr TEXT NOT NULL,
            png TEXT NOT NULL,
            bytes BIGINT NOT NULL,
            stats_json TEXT NOT NULL,
            PRIMARY KEY (job_id, frame)
        )",
            "CREATE TABLE strips (
            job_id TEXT NOT NULL,
            frame BIGINT NOT NULL,
            x0 BIGINT NOT NULL,
            x1 BIGINT NOT NULL,
            worker TEXT NOT NULL,
            path TEXT NOT NULL,
            PRIMARY KEY (job_id, frame, x0)
        )",
            "CREATE TABLE workers (
            addr TEXT PRIMARY KEY,
            strips_done BIGINT NOT NULL,
            strips_failed BIGINT NOT NULL,
            last_seen_ms BIGINT NOT NULL
        )",
        ],
    ),
    (
        2,
        "tokens of users with roles, the audit log",
        &[
            "CREATE TABLE tokens (
                id TEXT PRIMARY KEY,
                user_name TEXT NOT NULL,
                role TEXT NOT NULL,
                hash TEXT NOT NULL,
                created_ms BIGINT NOT NULL,
                revoked_ms BIGINT NOT NULL DEFAULT 0
            )",
            "CREATE TABLE audit (
                id BIGINT PRIMARY KEY,
                at_ms BIGINT NOT NULL,
                actor TEXT NOT NULL,
                action TEXT NOT NULL,
                target TEXT NOT NULL,
                detail TEXT NOT NULL
            )",
            "INSERT INTO counters (name, value) VALUES ('audit', 0)",
        ],
    ),
    (
        3,
        "results' hashes, checked when served",
        &[
            "ALTER TABLE frames ADD COLUMN exr_hash TEXT NOT NULL DEFAULT ''",
            "ALTER TABLE frames ADD COLUMN png_hash TEXT NOT NULL DEFAULT ''",
        ],
    ),
];

/// A statement in `dialect`'s words.
pub(super) fn in_dialect(sql: &str, postgres: bool) -> String {
    sql.replace("{BYTES}", if postgres { "BYTEA" } else { "BLOB" })
}
