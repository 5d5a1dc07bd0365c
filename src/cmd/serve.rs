//! `d3il serve`: the leaderboard web service (pages, plots, JSON API, worker pool).

use crate::common::build::GIT_COMMIT;
use crate::common::flags::{server_config, DbArgs, EndpointArgs, LimitArgs, ZooArg};
use anyhow::Context;
use std::net::SocketAddr;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    pub db: DbArgs,
    /// Address to listen on (port 0 picks a free port).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub bind: SocketAddr,
    /// Also serve /metrics, /healthz and /readyz without credentials on
    /// this address, for a scraper on a private network (on --bind,
    /// /metrics needs an admin token); see docs/ops.md.
    #[arg(long)]
    pub metrics_bind: Option<SocketAddr>,
    /// Concurrent evaluations (sandboxed worker processes); default: number of cores.
    #[arg(long)]
    pub workers: Option<usize>,
    /// Project assets (MJCF, initial-state sets, CSS); default: $D3IL_ASSETS, the repository's assets/ (as built), assets/ next to the binary, or ./assets.
    #[arg(long)]
    pub assets: Option<PathBuf>,
    /// Largest accepted upload, MiB.
    #[arg(long, default_value_t = 256)]
    pub max_upload_mb: usize,
    /// Authenticated API requests per token per minute.
    #[arg(long, default_value_t = 60)]
    pub rate_limit: u32,
    /// Requests without a token per client address per minute (IPv6: per /64).
    #[arg(long, default_value_t = 1200)]
    pub anonymous_rate_limit: u32,
    /// Failed token checks per client address per minute; past it the
    /// address's requests with credentials get 429 until the minute is over.
    #[arg(long, default_value_t = 20)]
    pub failed_auth_limit: u32,
    /// Disk space one submitter's stored ONNX files may use, MiB (files of
    /// failed submissions are deleted and do not count); 0: no limit.
    #[arg(long, default_value_t = 4096)]
    pub max_disk_mb_per_submitter: u64,
    /// Uploads streamed to disk at once; more wait before their body is read.
    #[arg(long, default_value_t = 4)]
    pub max_concurrent_uploads: usize,
    /// Attempts per evaluation before a crashing job fails.
    #[arg(long, default_value_t = 3)]
    pub max_attempts: i64,
    /// Split each paper-protocol evaluation into this many shards of whole
    /// initial states, run by any worker slot or host (`d3il workers`) and
    /// merged when all are done; the result is bit-identical to one run.
    #[arg(long, default_value_t = 1)]
    pub shards: usize,
    /// Queue uploaded models without the submission-time dry run (a few
    /// sandboxed steps of the quick protocol); a model that cannot run then
    /// fails at its evaluation instead of being refused at submission.
    #[arg(long)]
    pub no_upload_dry_run: bool,
    /// Seconds a client has to send a request header (also the keep-alive
    /// idle timeout); then the connection is closed.
    #[arg(long, default_value_t = 20)]
    pub header_timeout: u64,
    /// Open connections of the whole server; more are closed at once.
    #[arg(long, default_value_t = 2048)]
    pub max_connections: usize,
    /// Seconds in all that a request body left unread by an early answer
    /// (a refused upload) is read on, so its client gets the answer; then
    /// the connection is closed however the body trickles in.
    #[arg(long, default_value_t = 60)]
    pub linger_timeout: u64,
    /// Open connections from one client address; more are closed at once
    /// (a trusted proxy's are not capped).
    #[arg(long, default_value_t = 128)]
    pub max_connections_per_client: usize,
    /// A reverse proxy in front of this server (an address, `10.0.0.5`, or a
    /// network, `10.0.0.0/8`; repeat it or separate with commas). Only for
    /// requests from these, the client address the per-address limits use
    /// is read from X-Forwarded-For: its right-most entry that is not a
    /// trusted proxy. Without it the header is ignored (docs/ops.md).
    #[arg(
        long = "trusted-proxy",
        value_name = "ADDR|CIDR",
        value_delimiter = ','
    )]
    pub trusted_proxies: Vec<d3il_server::client_addr::TrustedProxy>,
    /// Evaluations one submitter may start in any 24 hours: a plain
    /// submission is one, a robustness suite its level 0 and every level
    /// (7-18), a race two (admission refusals do not count; admin tokens
    /// have no quota; per-submitter overrides: `d3il token set-quota`);
    /// 0: no limit.
    #[arg(long, default_value_t = d3il_server::config::QuotaLimits::SERVE_DEFAULT.per_day)]
    pub quota_per_day: i64,
    /// Evaluations one submitter may start in total; 0: no limit.
    #[arg(long, default_value_t = d3il_server::config::QuotaLimits::SERVE_DEFAULT.total)]
    pub quota_total: i64,
    /// Evaluations of one submitter queued or running at once (a suite
    /// counts as its evaluations, a race as two); 0: no limit.
    #[arg(long, default_value_t = d3il_server::config::QuotaLimits::SERVE_DEFAULT.concurrent)]
    pub quota_concurrent: i64,
    /// Races (`POST /api/v1/races`) one submitter may have queued or
    /// running at once; 0: no limit.
    #[arg(long, default_value_t = d3il_server::config::QuotaLimits::SERVE_DEFAULT.races)]
    pub max_queued_races: i64,
    #[command(flatten)]
    pub limits: LimitArgs,
    #[command(flatten)]
    pub endpoints: EndpointArgs,
    /// The fidelity report of /fidelity, computed at start in the background
    /// by `d3il fidelity` (one thread, lowest priority, cached per build):
    /// `full` (paper protocol for the closed-loop policies), `quick` or `off`.
    #[arg(long, value_enum, default_value_t = FidelityArg::Full)]
    pub fidelity: FidelityArg,
    /// Niceness of the fidelity computation (0: run at normal priority).
    #[arg(long, default_value_t = 19, hide = true)]
    pub fidelity_nice: i32,
    /// Do not run the drift canary (`d3il verify`) at start: results then
    /// record no physics fingerprint and are kept apart from those that do.
    #[arg(long)]
    pub no_verify: bool,
    /// Rollout videos rendered at once (each a `d3il replay --video`
    /// process, apart from the evaluation workers).
    #[arg(long, default_value_t = 1)]
    pub video_renders: usize,
    /// Worker executable (default: this binary, run as `d3il worker`).
    #[arg(long, hide = true)]
    pub worker_exe: Option<PathBuf>,
    /// The zoo loaded at every start (docs/zoo.md): its cells
    /// show as evaluated rows marked with their data source.
    #[command(flatten)]
    pub zoo: ZooArg,
}

/// `d3il serve --fidelity`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FidelityArg {
    Full,
    Quick,
    Off,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut cfg = server_config(
        args.db,
        args.bind,
        args.worker_exe,
        args.workers,
        args.assets,
        &args.limits,
        &args.endpoints,
    )?;
    cfg.metrics_bind = args.metrics_bind;
    cfg.max_upload_bytes = args.max_upload_mb.max(1) << 20;
    cfg.rate_limit_per_minute = args.rate_limit.max(1);
    cfg.anonymous_rate_limit_per_minute = args.anonymous_rate_limit.max(1);
    cfg.failed_auth_per_minute = args.failed_auth_limit.max(1);
    cfg.max_disk_bytes_per_submitter =
        (args.max_disk_mb_per_submitter > 0).then_some(args.max_disk_mb_per_submitter << 20);
    cfg.max_concurrent_uploads = args.max_concurrent_uploads.max(1);
    anyhow::ensure!(args.max_attempts >= 1, "--max-attempts must be at least 1");
    cfg.max_attempts = args.max_attempts;
    cfg.shards = args.shards.max(1);
    cfg.dry_run_uploads = !args.no_upload_dry_run;
    anyhow::ensure!(
        args.quota_per_day >= 0
            && args.quota_total >= 0
            && args.quota_concurrent >= 0
            && args.max_queued_races >= 0,
        "--quota-per-day, --quota-total, --quota-concurrent and --max-queued-races must be 0 (no limit) or more"
    );
    cfg.quotas = d3il_server::config::QuotaLimits {
        per_day: args.quota_per_day,
        total: args.quota_total,
        concurrent: args.quota_concurrent,
        races: args.max_queued_races,
    };
    anyhow::ensure!(
        args.header_timeout >= 1
            && args.max_connections >= 1
            && args.max_connections_per_client >= 1
            && args.linger_timeout >= 1,
        "--header-timeout, --max-connections, --max-connections-per-client and --linger-timeout must be at least 1"
    );
    cfg.connections = d3il_server::config::ConnectionLimits {
        header_read_timeout: std::time::Duration::from_secs(args.header_timeout),
        max_connections: args.max_connections,
        max_connections_per_client: args.max_connections_per_client,
        trusted_proxies: args.trusted_proxies.into_iter().collect(),
        linger_deadline: std::time::Duration::from_secs(args.linger_timeout),
    };
    cfg.fidelity.mode = match args.fidelity {
        FidelityArg::Full => Some(d3il_protocol::fidelity::FidelityMode::Full),
        FidelityArg::Quick => Some(d3il_protocol::fidelity::FidelityMode::Quick),
        FidelityArg::Off => None,
    };
    cfg.fidelity.nice = args.fidelity_nice;
    cfg.canary.run = !args.no_verify;
    cfg.canary.git_commit = GIT_COMMIT.to_string();
    cfg.videos.renders = args.video_renders.max(1);
    cfg.zoo = args.zoo.dir_in(&cfg.assets_dir);
    d3il_server::cli::serve_blocking(cfg).context("d3il serve failed")?;
    Ok(())
}
