-- Issue 40: the robustness track. `submissions.suite`: the perturbation suite
-- a submission asked for ('robustness'), NULL for a plain evaluation (its
-- level 0 is stored as the plain result too, in `results`). One
-- `robustness_results` row per such submission once evaluated: the suite
-- file's name and sha256 (rows of different suite versions are never ranked
-- together), the overall robustness score with its interval (NULL when level
-- 0 had no success), `summary_json` (the RobustnessResult without rollout
-- records: what boards and tables read) and `document_json` (the whole
-- document, `GET /api/v1/submissions/{id}/robustness`).
ALTER TABLE submissions ADD COLUMN suite TEXT;
CREATE TABLE robustness_results (
    submission_id   INTEGER PRIMARY KEY REFERENCES submissions(id),
    suite           TEXT NOT NULL,
    suite_sha256    TEXT NOT NULL,
    overall         REAL,
    overall_ci_low  REAL,
    overall_ci_high REAL,
    summary_json    TEXT NOT NULL,
    document_json   TEXT NOT NULL,
    created_at      INTEGER NOT NULL DEFAULT (unixepoch())
);
