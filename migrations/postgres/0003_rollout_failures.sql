-- As migrations/sqlite/0003_rollout_failures.sql.
ALTER TABLE results ADD COLUMN rollouts_ended_unstable BIGINT NOT NULL DEFAULT 0;
ALTER TABLE rollouts ADD COLUMN failure_json TEXT;
