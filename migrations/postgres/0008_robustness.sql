-- As migrations/sqlite/0008_robustness.sql.
ALTER TABLE submissions ADD COLUMN suite TEXT;
CREATE TABLE robustness_results (
    submission_id   BIGINT PRIMARY KEY REFERENCES submissions(id),
    suite           TEXT NOT NULL,
    suite_sha256    TEXT NOT NULL,
    overall         DOUBLE PRECISION,
    overall_ci_low  DOUBLE PRECISION,
    overall_ci_high DOUBLE PRECISION,
    summary_json    TEXT NOT NULL,
    document_json   TEXT NOT NULL,
    created_at      BIGINT NOT NULL DEFAULT (EXTRACT(EPOCH FROM now())::BIGINT)
);
