-- Issue 16: a rollout whose simulation became unstable ends as a failure with
-- a recorded reason instead of failing the whole evaluation.
-- `rollouts_ended_unstable`: how many rollouts of the result ended that way.
-- `failure_json`: the rollout's RolloutFailure (reason, message, step), NULL
-- for a rollout that ran its course (and for results stored before).
ALTER TABLE results ADD COLUMN rollouts_ended_unstable INTEGER NOT NULL DEFAULT 0;
ALTER TABLE rollouts ADD COLUMN failure_json TEXT;
