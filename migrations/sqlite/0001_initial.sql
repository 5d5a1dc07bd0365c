-- D3IL leaderboard schema (issue 7). Times are unix seconds (INTEGER).

CREATE TABLE submitters (
    id          INTEGER PRIMARY KEY,
    name        TEXT NOT NULL UNIQUE,
    created_at  INTEGER NOT NULL DEFAULT (unixepoch())
);

-- Only the SHA-256 of a token is stored; `prefix` (first characters) lets a
-- person recognise a token in listings without it being usable.
CREATE TABLE api_tokens (
    id            INTEGER PRIMARY KEY,
    submitter_id  INTEGER NOT NULL REFERENCES submitters(id),
    token_sha256  TEXT NOT NULL UNIQUE,
    prefix        TEXT NOT NULL,
    created_at    INTEGER NOT NULL DEFAULT (unixepoch()),
    last_used_at  INTEGER,
    revoked_at    INTEGER
);

-- Methods with the paper's properties (Table 1 of the paper).
CREATE TABLE methods (
    id            INTEGER PRIMARY KEY,
    name          TEXT NOT NULL UNIQUE,
    history       INTEGER,
    backbone      TEXT,
    prediction    TEXT,
    diversity     TEXT,
    code_url      TEXT,
    paper_url     TEXT,
    description   TEXT,
    -- 1 for the paper's eleven baselines.
    from_paper    INTEGER NOT NULL DEFAULT 0,
    -- Paper-reported inference times (ms per query).
    state_inference_ms  REAL,
    image_inference_ms  REAL,
    submitter_id  INTEGER REFERENCES submitters(id),
    created_at    INTEGER NOT NULL DEFAULT (unixepoch())
);

-- The paper's published numbers, loaded once and never re-evaluated.
-- `control` is '' when not applicable so that the UNIQUE key works (NULLs are distinct in SQLite).
CREATE TABLE reported_results (
    id            INTEGER PRIMARY KEY,
    paper_table   TEXT NOT NULL,
    method_id     INTEGER NOT NULL REFERENCES methods(id),
    task_title    TEXT NOT NULL,
    obs_type      TEXT NOT NULL,
    data_fraction REAL NOT NULL,
    control       TEXT NOT NULL DEFAULT '',
    success_mean  REAL NOT NULL,
    success_std   REAL NOT NULL,
    success_bold  INTEGER NOT NULL,
    entropy_mean  REAL NOT NULL,
    entropy_std   REAL NOT NULL,
    entropy_bold  INTEGER NOT NULL,
    n_seeds       INTEGER NOT NULL,
    subtasks_json TEXT,
    UNIQUE (paper_table, method_id, task_title, obs_type, data_fraction, control)
);

CREATE TABLE submissions (
    id             INTEGER PRIMARY KEY,
    method_id      INTEGER NOT NULL REFERENCES methods(id),
    submitter_id   INTEGER REFERENCES submitters(id),
    task           TEXT NOT NULL,
    obs_type       TEXT NOT NULL,
    training_seed  INTEGER NOT NULL,
    data_fraction  REAL NOT NULL,
    protocol       TEXT NOT NULL,
    policy_kind    TEXT NOT NULL CHECK (policy_kind IN ('onnx', 'remote')),
    onnx_sha256    TEXT,
    onnx_bytes     INTEGER,
    onnx_path      TEXT,
    endpoint_url   TEXT,
    manifest_json  TEXT NOT NULL,
    status         TEXT NOT NULL CHECK (status IN ('queued', 'running', 'completed', 'failed')),
    error_kind     TEXT,
    error_message  TEXT,
    created_at     INTEGER NOT NULL DEFAULT (unixepoch()),
    updated_at     INTEGER NOT NULL DEFAULT (unixepoch())
);

-- One training seed per method/task/observation/fraction/protocol; a failed
-- submission does not block a new attempt.
CREATE UNIQUE INDEX submissions_unique_seed
    ON submissions (method_id, task, obs_type, data_fraction, protocol, training_seed)
    WHERE status != 'failed';

-- The durable queue: a job is leased by a worker slot; the lease is extended by
-- heartbeats; an expired lease (or a server restart) puts it back in the queue.
CREATE TABLE jobs (
    id               INTEGER PRIMARY KEY,
    submission_id    INTEGER NOT NULL UNIQUE REFERENCES submissions(id),
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
    finished_at      INTEGER
);
CREATE INDEX jobs_state ON jobs (state, id);

-- One result per submission (the UNIQUE key makes result writes idempotent).
CREATE TABLE results (
    id                     INTEGER PRIMARY KEY,
    submission_id          INTEGER NOT NULL UNIQUE REFERENCES submissions(id),
    success_rate           REAL NOT NULL,
    success_ci_low         REAL NOT NULL,
    success_ci_high        REAL NOT NULL,
    behaviour_entropy      REAL NOT NULL,
    behaviour_ci_low       REAL NOT NULL,
    behaviour_ci_high      REAL NOT NULL,
    conditional_entropy    REAL NOT NULL,
    conditional_ci_low     REAL NOT NULL,
    conditional_ci_high    REAL NOT NULL,
    stacking_json          TEXT,
    inference_ms           REAL NOT NULL,
    manifest_json          TEXT NOT NULL,
    per_context_json       TEXT NOT NULL,
    created_at             INTEGER NOT NULL DEFAULT (unixepoch())
);

CREATE TABLE rollouts (
    id             INTEGER PRIMARY KEY,
    submission_id  INTEGER NOT NULL REFERENCES submissions(id),
    context_index  INTEGER NOT NULL,
    rollout_index  INTEGER NOT NULL,
    success        INTEGER NOT NULL,
    behaviour_json TEXT NOT NULL,
    steps          INTEGER NOT NULL,
    -- End-effector xy path (Avoiding), JSON array of [x, y].
    path_json      TEXT,
    UNIQUE (submission_id, context_index, rollout_index)
);
