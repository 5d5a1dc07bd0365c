-- Issue 31: what a policy did. `ending`: how the rollout ended (the protocol's
-- Ending: task_success, task_ended, time_limit, sim_unstable, step_cap), NULL
-- for results stored before it was recorded. `trace_json`: the rollout's
-- RolloutTrace (actions, per-step digests, TCP and object paths, poses,
-- landmarks; packed, a few kB), NULL for results stored before traces and for
-- the copies of a rollout simulated once per initial state (they share the
-- trace of their state's rollout 0).
ALTER TABLE rollouts ADD COLUMN ending TEXT;
ALTER TABLE rollouts ADD COLUMN trace_json TEXT;
