//! `d3il workers --db postgres://… --policy-store DIR`: a worker host. It runs
//! only the worker pool, leasing jobs from the PostgreSQL queue that front
//! ends (`d3il serve`) and other hosts share; see docs/cluster.md.

use anyhow::Context;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    pub db: crate::common::flags::DbArgs,
    /// Concurrent evaluations on this host (sandboxed worker processes), plus
    /// one slot for quick-protocol jobs; default: number of cores.
    #[arg(long)]
    pub workers: Option<usize>,
    /// Project assets (MJCF, initial-state sets); default as for `d3il serve`.
    #[arg(long)]
    pub assets: Option<PathBuf>,
    /// Seconds a lease lasts without a heartbeat; a host that dies loses its
    /// jobs to other hosts after this long.
    #[arg(long, default_value_t = 30)]
    pub lease_seconds: i64,
    /// Serve this host's /metrics, /healthz and /readyz (no credentials) on
    /// this address, for a scraper on a private network; see docs/ops.md.
    #[arg(long)]
    pub metrics_bind: Option<std::net::SocketAddr>,
    #[command(flatten)]
    pub limits: crate::common::flags::LimitArgs,
    #[command(flatten)]
    pub endpoints: crate::common::flags::EndpointArgs,
    /// Do not run the drift canary (`d3il verify`) at start: this host's
    /// results then record no physics fingerprint and are kept apart from
    /// those that do (as for `d3il serve --no-verify`).
    #[arg(long)]
    pub no_verify: bool,
    /// Worker executable (default: this binary, run as `d3il worker`).
    #[arg(long, hide = true)]
    pub worker_exe: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // The bind address is unused: a worker host serves no HTTP.
    let unused = std::net::SocketAddr::from(([127, 0, 0, 1], 0));
    let mut cfg = crate::common::flags::server_config(
        args.db,
        unused,
        args.worker_exe,
        args.workers.map(|w| w.max(1)),
        args.assets,
        &args.limits,
        &args.endpoints,
    )?;
    anyhow::ensure!(
        args.lease_seconds >= 3,
        "--lease-seconds must be at least 3"
    );
    cfg.lease_seconds = args.lease_seconds;
    cfg.metrics_bind = args.metrics_bind;
    // The results are this host's: they record its build and the canary's
    // physics fingerprint, as those of `d3il serve`'s own slots do.
    cfg.canary.run = !args.no_verify;
    cfg.canary.git_commit = crate::common::build::GIT_COMMIT.to_string();
    d3il_server::cli::workers_blocking(cfg).context("d3il workers failed")?;
    Ok(())
}
