-- As migrations/sqlite/0007_rollout_traces.sql.
ALTER TABLE rollouts ADD COLUMN ending TEXT;
ALTER TABLE rollouts ADD COLUMN trace_json TEXT;
