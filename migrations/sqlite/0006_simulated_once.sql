-- Whether a submission's rollouts of one initial state are simulated once (a
-- deterministic policy: an ONNX graph without a `noise` input; the result
-- manifest's `simulated_once`). Learnt from the dry run at submission and from
-- the result; NULL when not known (no dry run, or stored before this column).
-- Queue estimates keep such runs apart: they take a fraction of the time.
ALTER TABLE submissions ADD COLUMN simulated_once BOOLEAN;
