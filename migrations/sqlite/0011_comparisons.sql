-- Issue 41: sequential comparisons of two submissions on the server
-- (`POST /api/v1/comparisons`). A race job runs both submissions' policies
-- interleaved on the same initial states and stops when the anytime-valid
-- paired test decides (docs/sequential.md).
-- `status`: queued | running | completed | failed.
-- `live_json`: the race's progress after its latest pair (d3il_protocol::race::RaceProgress
-- plus the paired counts), written while it runs.
-- `report_json`: the finished race's report (d3il_protocol::race::RaceReport).
CREATE TABLE comparisons (
    id            INTEGER PRIMARY KEY,
    submission_a  INTEGER NOT NULL REFERENCES submissions(id),
    submission_b  INTEGER NOT NULL REFERENCES submissions(id),
    submitter_id  INTEGER REFERENCES submitters(id),
    task          TEXT NOT NULL,
    protocol      TEXT NOT NULL,
    seed          INTEGER NOT NULL,
    alpha         REAL NOT NULL,
    delta         REAL,
    status        TEXT NOT NULL DEFAULT 'queued',
    live_json     TEXT,
    report_json   TEXT,
    error_message TEXT,
    created_at    INTEGER NOT NULL,
    updated_at    INTEGER NOT NULL
);
CREATE INDEX comparisons_status ON comparisons (status, id);
