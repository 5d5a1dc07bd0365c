-- Issue 52: races wait in the durable queue and can be cancelled.
-- A queued race is claimed by a front end's race slot with a lease
-- (`lease_owner`, `lease_expires_at`), like a job; a restart requeues the
-- leases of its own (SQLite) or lets them expire (PostgreSQL).
-- `status` gains `cancelled` (by its starter or an admin: `cancelled_by`).
ALTER TABLE comparisons ADD COLUMN lease_owner TEXT;
ALTER TABLE comparisons ADD COLUMN lease_expires_at INTEGER;
ALTER TABLE comparisons ADD COLUMN cancelled_by TEXT;
-- The quota counts a submitter's races by time and by status.
CREATE INDEX comparisons_submitter ON comparisons (submitter_id, created_at);
