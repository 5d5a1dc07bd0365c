-- Issue 42: submission quotas, moderation and the audit log.

-- Per-submitter quota overrides (`d3il token set-quota`, the admin API):
-- NULL keeps the server's default (`d3il serve --quota-*`), 0 is no limit.
ALTER TABLE submitters ADD COLUMN quota_per_day INTEGER;
ALTER TABLE submitters ADD COLUMN quota_total INTEGER;
ALTER TABLE submitters ADD COLUMN quota_concurrent INTEGER;

-- A withdrawn submission is kept (its page shows the reason) but leaves the
-- boards and tables.
ALTER TABLE submissions ADD COLUMN withdrawn_at INTEGER;
ALTER TABLE submissions ADD COLUMN withdrawn_reason TEXT;
ALTER TABLE submissions ADD COLUMN withdrawn_by TEXT;

-- A method an operator marked as a baseline: its rows say so on the boards.
ALTER TABLE methods ADD COLUMN baseline INTEGER NOT NULL DEFAULT 0;

-- Every admin action: who (the admin token's submitter, or `cli:<user>`
-- for the d3il command on the database), what, on what, when.
CREATE TABLE audit_log (
    id      INTEGER PRIMARY KEY,
    at      INTEGER NOT NULL DEFAULT (unixepoch()),
    actor   TEXT NOT NULL,
    action  TEXT NOT NULL,
    target  TEXT NOT NULL,
    detail  TEXT NOT NULL DEFAULT ''
);
CREATE INDEX audit_log_at ON audit_log (at, id);

-- The quota counts: a submitter's submissions by time and by status.
CREATE INDEX submissions_submitter ON submissions (submitter_id, created_at);
