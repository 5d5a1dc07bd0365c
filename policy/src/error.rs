use d3il_protocol::ErrorKind;

/// Everything that can go wrong loading or querying a policy. Each message says
/// what was wrong and what was expected, so it can be shown to the submitter.
#[derive(Debug, thiserror::Error)]
pub enum PolicyError {
    // ---- ONNX file / manifest problems (ErrorKind::BadModel) ----
    #[error("the ONNX file could not be parsed: {0}; upload the .onnx file exported by torch.onnx.export (not a checkpoint, archive or truncated copy)")]
    Unparsable(String),
    #[error("the ONNX model is not supported: {0}")]
    Unsupported(String),
    #[error("{0}")]
    Mismatch(String),
    #[error("the policy manifest is invalid: {0}")]
    BadManifest(String),

    // ---- Wrong use of the API by the evaluator itself (ErrorKind::Internal) ----
    #[error("evaluator bug: {0}")]
    Caller(String),
    /// The operator's set-up is wrong (e.g. an unusable extra CA).
    #[error("the evaluator's configuration is invalid: {0}")]
    Config(String),

    // ---- Runtime problems with the policy output (ErrorKind::BadAction) ----
    #[error("policy returned a non-finite action ({value}) for rollout {rollout} at step {step} (action {action} of the chunk, component {component}); actions must be finite numbers")]
    NonFinite {
        rollout: u64,
        step: u64,
        action: usize,
        component: usize,
        value: f32,
    },
    #[error("policy returned {got} for a query of {batch} rollouts (first rollout {rollout} at step {step}); expected {expected}")]
    WrongShape {
        got: String,
        expected: String,
        batch: usize,
        rollout: u64,
        step: u64,
    },
    #[error("ONNX inference failed for the query of rollout {rollout} at step {step}: {message}")]
    Inference {
        rollout: u64,
        step: u64,
        message: String,
    },

    // ---- Remote endpoints ----
    #[error("endpoint `{url}` refused: {reason}")]
    BadEndpoint { url: String, reason: String },
    /// A failed TLS handshake or a ws/wss mismatch; `reason` is the whole
    /// submitter-facing message (names the host and what to fix).
    #[error("{reason}")]
    Tls { url: String, reason: String },
    #[error("could not connect to the policy server at `{url}`: {reason}; check that the server is running and reachable")]
    Connect { url: String, reason: String },
    #[error("the policy server did not answer the {request} within {deadline_ms} ms; answer every request within the deadline (batch your inference, or ask for a larger deadline)")]
    Late { request: String, deadline_ms: u64 },
    #[error("the policy server sent a {request} reply larger than the {limit} byte frame limit; send float32 arrays and nothing else large")]
    Oversized { request: String, limit: u64 },
    #[error("the policy server sent a malformed {request} reply: {reason} (see docs/remote-protocol.md)")]
    Malformed { request: String, reason: String },
    #[error("the policy server closed the connection during the {request}{detail}; it must stay connected for the whole evaluation")]
    Disconnected { request: String, detail: String },
    #[error("the policy server reported an error on the {request}: {message}")]
    ServerError { request: String, message: String },
    #[error(
        "the policy server speaks protocol version {got}; this evaluator speaks version {expected}"
    )]
    ProtocolVersion { got: u64, expected: u64 },
}

impl PolicyError {
    /// The category a submitter can act on (protocol contract).
    pub fn kind(&self) -> ErrorKind {
        use PolicyError::*;
        match self {
            Unparsable(_) | Unsupported(_) | Mismatch(_) | BadManifest(_) => ErrorKind::BadModel,
            Caller(_) | Config(_) => ErrorKind::Internal,
            NonFinite { .. } | WrongShape { .. } | Inference { .. } => ErrorKind::BadAction,
            // A certificate or ws/wss mismatch fails the same way on a retry.
            BadEndpoint { .. } | Tls { .. } => ErrorKind::BadEndpoint,
            Connect { .. }
            | Late { .. }
            | Oversized { .. }
            | Malformed { .. }
            | Disconnected { .. }
            | ServerError { .. }
            | ProtocolVersion { .. } => ErrorKind::Remote,
        }
    }
}
