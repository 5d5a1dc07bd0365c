-- A remote endpoint's optional shared secret (docs/remote-protocol.md,
-- "Shared secret"): the evaluator sends it in the WebSocket handshake so that
-- a published endpoint can refuse everyone else. Kept as text because the
-- evaluator must send it as it is; no page or API answer shows it, not even
-- to its submitter. NULL for ONNX uploads and endpoints without a secret.
ALTER TABLE submissions ADD COLUMN endpoint_secret TEXT;
