//! The state every request handler shares.

use crate::config::ServerConfig;
use crate::queue::{JobRunner, QueueSignal};
use crate::ratelimit::RateLimiter;
use crate::sandbox_status::SandboxStatus;
use crate::store::Store;
use std::sync::Arc;

#[derive(Clone)]
pub struct AppState {
    pub store: Store,
    pub cfg: Arc<ServerConfig>,
    pub signal: QueueSignal,
    pub limiter: Arc<RateLimiter>,
    /// Anonymous requests and failed token checks per client address.
    pub client_limits: Arc<crate::ratelimit::ClientLimits>,
    /// Uploads streaming at once (`max_concurrent_uploads`).
    pub uploads: Arc<tokio::sync::Semaphore>,
    /// Used for endpoint conformance dry-runs.
    pub runner: Arc<dyn JobRunner>,
    /// The sandbox mechanisms in force (admin page).
    pub sandbox: Arc<SandboxStatus>,
    /// Rendered results documents of finished submissions.
    pub finished: Arc<crate::cache::FinishedCache>,
    /// Rollout videos: the render pool and its cache.
    pub videos: Arc<crate::videos::Videos>,
    /// The fidelity report (`/fidelity`), computed in the background.
    pub fidelity: Arc<crate::fidelity::FidelityReports>,
    /// The drift canary's outcome and this build's identity.
    pub canary: Arc<crate::canary::Canary>,
    /// Metrics and readiness (`/metrics`, `/readyz`).
    pub telemetry: Arc<crate::telemetry::Telemetry>,
}
