-- As migrations/sqlite/0005_job_shards.sql: one row of `jobs` per shard.
ALTER TABLE jobs DROP CONSTRAINT jobs_submission_id_key;
ALTER TABLE jobs ADD COLUMN shard_index BIGINT NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN shard_count BIGINT NOT NULL DEFAULT 1;
ALTER TABLE jobs ADD COLUMN part_json TEXT;
ALTER TABLE jobs ADD CONSTRAINT jobs_submission_shard UNIQUE (submission_id, shard_index);
