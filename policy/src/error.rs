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

    // ---- Resource limits (ErrorKind::MemoryLimit) ----
    /// The runtime could not allocate a tensor (the model asks for more memory
    /// than the worker's address-space limit allows, e.g. a Tile bomb).
    #[error("the ONNX runtime ran out of memory {during} ({detail}); the model needs more memory than the worker's memory limit allows: make its tensors smaller or ask for a higher limit")]
    OutOfMemory { during: String, detail: String },

    // ---- Remote endpoints ----
    #[error("endpoint `{url}` refused: {reason}")]
    BadEndpoint { url: String, reason: String },
    /// A failed TLS handshake or a ws/wss mismatch; `reason` is the whole
    /// submitter-facing message (names the host and what to fix).
    #[error("{reason}")]
    Tls { url: String, reason: String },
    /// The policy server refused the evaluator in the WebSocket handshake
    /// (HTTP 401 or 403): the endpoint's shared secret is missing or wrong.
    #[error("the policy server at `{url}` refused the evaluator (HTTP {status}{answer}); {}", if *.sent_secret {
        "the endpoint secret sent does not match the server's: submit the endpoint again with the secret its server was started with (`endpoint_secret`, docs/remote-protocol.md)"
    } else {
        "no endpoint secret was sent: if the server was started with a secret (--secret or $D3IL_ENDPOINT_SECRET), submit the endpoint with the same secret (`endpoint_secret`, docs/remote-protocol.md)"
    })]
    Unauthorized {
        url: String,
        status: u16,
        /// ": " and the start of the server's answer, or empty.
        answer: String,
        sent_secret: bool,
    },
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
            OutOfMemory { .. } => ErrorKind::MemoryLimit,
            // A certificate or ws/wss mismatch fails the same way on a retry.
            // So does a refused secret.
            BadEndpoint { .. } | Tls { .. } | Unauthorized { .. } => ErrorKind::BadEndpoint,
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

/// The text of a caught panic's payload.
pub(crate) fn panic_text(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<String>()
        .cloned()
        .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "unknown panic".into())
}

/// Whether a runtime failure is memory exhaustion. tract asserts that its
/// tensor allocations succeed ("failed to allocate Layout { .. }", or a bare
/// `!self.data.is_null()` assertion) instead of returning an error, so under
/// the worker's address-space limit a too-large tensor arrives as a panic.
pub(crate) fn is_out_of_memory(text: &str) -> bool {
    text.contains("failed to allocate")
        || text.contains("data.is_null()")
        || text.contains("capacity overflow")
        || text.contains("memory allocation of")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tract_allocation_failures_are_memory_exhaustion() {
        assert!(is_out_of_memory(
            "failed to allocate Layout { size: 4398046511104, align: 128 (1 << 7) }"
        ));
        assert!(is_out_of_memory("assertion failed: !self.data.is_null()"));
        assert!(!is_out_of_memory("Tiling [1, 1] by [2]"));
        let e = PolicyError::OutOfMemory {
            during: "in the query of rollout 0 at step 0".into(),
            detail: "failed to allocate".into(),
        };
        assert_eq!(e.kind(), ErrorKind::MemoryLimit);
    }
}
