-- Issue 50: the zoo, the paper's methods trained here with the reference
-- code on demonstrations recorded from our tasks (assets/zoo/), loaded at
-- every start as finished submissions of the built-in `zoo` submitter.

-- Where a submission's training data came from: NULL for what submitters
-- send (trained on whatever they trained on), else the zoo's words
-- ("trained here on d3il demos v1"). Rows of different data sources are
-- never aggregated or ranked together.
ALTER TABLE submissions ADD COLUMN data_source TEXT;

-- The same training seed of a method may exist once per data source: the
-- zoo's BC-MLP seed 0 does not block a submitter's BC-MLP seed 0.
DROP INDEX submissions_unique_seed;
CREATE UNIQUE INDEX submissions_unique_seed
    ON submissions (method_id, task, obs_type, data_fraction, protocol, training_seed, COALESCE(data_source, ''))
    WHERE status != 'failed';

-- One row per zoo cell (`<task>/<method-slug>-s<seed>`): the submission it
-- is stored as, the sha256 of the result document loaded (a changed file is
-- loaded again into the same submission) and the provenance record as given.
CREATE TABLE zoo_cells (
    id               INTEGER PRIMARY KEY,
    cell             TEXT NOT NULL UNIQUE,
    submission_id    INTEGER NOT NULL UNIQUE REFERENCES submissions(id),
    result_sha256    TEXT NOT NULL,
    provenance_json  TEXT NOT NULL,
    loaded_at        INTEGER NOT NULL
);
