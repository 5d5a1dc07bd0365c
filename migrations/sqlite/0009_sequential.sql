-- Issue 41: live anytime-valid progress and cancel.
-- `jobs.outcomes_json`: the outcomes the running attempt has reported so far,
-- in the order the worker reported them (a JSON array of
-- [successes, rollouts] per initial state); reset when an attempt starts,
-- kept when the job ends (a cancelled evaluation's partial result).
-- `submissions.cancelled_at` / `cancelled_by`: when and by whom (token name)
-- an evaluation was cancelled; such a submission is failed with
-- error_kind 'cancelled' and never ranked.
ALTER TABLE jobs ADD COLUMN outcomes_json TEXT;
ALTER TABLE submissions ADD COLUMN cancelled_at INTEGER;
ALTER TABLE submissions ADD COLUMN cancelled_by TEXT;
