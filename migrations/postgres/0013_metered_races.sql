-- As migrations/sqlite/0013_metered_races.sql.
ALTER TABLE comparisons ADD COLUMN lease_owner TEXT;
ALTER TABLE comparisons ADD COLUMN lease_expires_at BIGINT;
ALTER TABLE comparisons ADD COLUMN cancelled_by TEXT;
CREATE INDEX comparisons_submitter ON comparisons (submitter_id, created_at);
