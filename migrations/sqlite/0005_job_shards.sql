-- Issue 19: a paper-protocol job may be split into shards of whole initial
-- states that any worker host runs; each shard is a row of `jobs` (leased,
-- heartbeated and retried on its own) and its part is kept in `part_json`
-- until the last shard completes and the parts are merged into the result.
-- A plain job is its one shard (index 0 of 1). SQLite cannot drop the old
-- UNIQUE (submission_id), so the table is rebuilt (no table refers to jobs).
CREATE TABLE jobs_sharded (
    id               INTEGER PRIMARY KEY,
    submission_id    INTEGER NOT NULL REFERENCES submissions(id),
    state            TEXT NOT NULL CHECK (state IN ('queued', 'leased', 'done', 'failed')),
    attempts         INTEGER NOT NULL DEFAULT 0,
    max_attempts     INTEGER NOT NULL,
    lease_owner      TEXT,
    lease_expires_at INTEGER,
    heartbeat_at     INTEGER,
    rollouts_done    INTEGER NOT NULL DEFAULT 0,
    rollouts_total   INTEGER NOT NULL DEFAULT 0,
    error_kind       TEXT,
    error_message    TEXT,
    sandbox_json     TEXT,
    created_at       INTEGER NOT NULL DEFAULT (unixepoch()),
    started_at       INTEGER,
    finished_at      INTEGER,
    shard_index      INTEGER NOT NULL DEFAULT 0,
    shard_count      INTEGER NOT NULL DEFAULT 1,
    part_json        TEXT,
    UNIQUE (submission_id, shard_index)
);
INSERT INTO jobs_sharded (id, submission_id, state, attempts, max_attempts, lease_owner, lease_expires_at,
    heartbeat_at, rollouts_done, rollouts_total, error_kind, error_message, sandbox_json, created_at,
    started_at, finished_at)
SELECT id, submission_id, state, attempts, max_attempts, lease_owner, lease_expires_at,
    heartbeat_at, rollouts_done, rollouts_total, error_kind, error_message, sandbox_json, created_at,
    started_at, finished_at FROM jobs;
DROP TABLE jobs;
ALTER TABLE jobs_sharded RENAME TO jobs;
CREATE INDEX jobs_state ON jobs (state, id);
