//! Flag groups several commands share, defined once so that each flag reads
//! and checks the same everywhere: the database (`--db`, `--policy-store`),
//! the sandbox limits of an evaluation, the servers' private-endpoint
//! setting, the zoo (`--zoo`) and the robot's look (`--look`); and the
//! server configuration `d3il serve` and `d3il workers` build from them.

use anyhow::Context;
use d3il_evaluator::sim::scene::{best_look, RobotLook};
use d3il_protocol::Limits;
use d3il_server::ops::DbTarget;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

/// `--db` and `--policy-store`, for every command that opens the
/// leaderboard's store (`serve`, `workers`, `token`, `tables`, `db`).
#[derive(clap::Args, Debug, Clone)]
pub struct DbArgs {
    /// The database: a SQLite file (created and migrated if missing; the
    /// embedded default) or a PostgreSQL URL `postgres://user@host/db`
    /// shared by several front ends and worker hosts (docs/cluster.md).
    #[arg(long, default_value = "d3il.sqlite")]
    pub db: DbTarget,
    /// Directory of uploaded policies (they go in its `policies/`). Needed
    /// with PostgreSQL: the same shared directory (e.g. NFS) on every host,
    /// so any host can run any job. Default with SQLite: `<db stem>-data/`
    /// next to the database file.
    #[arg(long)]
    pub policy_store: Option<PathBuf>,
}

/// The sandbox limits of an evaluation, as flags shared by `d3il serve`,
/// `d3il workers` and `d3il eval` (the defaults are `Limits::default()`).
#[derive(clap::Args, Debug, Clone)]
pub struct LimitArgs {
    /// Address-space limit of a worker, MiB.
    #[arg(long, default_value_t = Limits::default().memory_bytes >> 20, help_heading = "Sandbox limits")]
    pub memory_mb: u64,
    /// CPU-time limit of a worker, seconds.
    #[arg(long, default_value_t = Limits::default().cpu_seconds, help_heading = "Sandbox limits")]
    pub cpu_seconds: u64,
    /// Wall-clock limit of one evaluation, seconds.
    #[arg(long, default_value_t = Limits::default().wall_seconds, help_heading = "Sandbox limits")]
    pub wall_seconds: u64,
    /// Open-file limit of a worker.
    #[arg(long, default_value_t = Limits::default().open_files, help_heading = "Sandbox limits")]
    pub open_files: u64,
    /// Largest file a worker may write, MiB.
    #[arg(long, default_value_t = Limits::default().file_size_bytes >> 20, help_heading = "Sandbox limits")]
    pub file_size_mb: u64,
    /// Deadline of each request to a remote endpoint, milliseconds.
    #[arg(long, default_value_t = Limits::default().remote_deadline_ms, help_heading = "Sandbox limits")]
    pub remote_deadline_ms: u64,
    /// Largest frame a remote endpoint may send, MiB.
    #[arg(long, default_value_t = Limits::default().remote_frame_bytes >> 20, help_heading = "Sandbox limits")]
    pub remote_frame_mb: u64,
}

/// `d3il serve` and `d3il workers`: whether submitted endpoints may be on
/// loopback or private addresses. Every refusal of such an endpoint names
/// this flag (`d3il_protocol::address::ALLOW_PRIVATE_SETTING`). `d3il eval`
/// has no such setting: it connects to whatever its user names.
#[derive(clap::Args, Debug, Clone)]
pub struct EndpointArgs {
    /// Evaluate submitted remote endpoints on loopback and private addresses
    /// too (a trusted network, tests); without it they are refused at
    /// submission, at the dry run and in the worker.
    #[arg(long, help_heading = "Sandbox limits")]
    pub allow_private_endpoints: bool,
}

impl LimitArgs {
    /// The limits these flags give; every value must be at least 1.
    /// `allow_private_endpoints` is the caller's: `d3il eval` always allows
    /// them, a server only with `EndpointArgs`.
    pub fn limits(&self, allow_private_endpoints: bool) -> anyhow::Result<Limits> {
        for (flag, v) in [
            ("--memory-mb", self.memory_mb),
            ("--cpu-seconds", self.cpu_seconds),
            ("--wall-seconds", self.wall_seconds),
            ("--open-files", self.open_files),
            ("--file-size-mb", self.file_size_mb),
            ("--remote-deadline-ms", self.remote_deadline_ms),
            ("--remote-frame-mb", self.remote_frame_mb),
        ] {
            anyhow::ensure!(v >= 1, "{flag} must be at least 1 (got {v})");
        }
        Ok(Limits {
            memory_bytes: self.memory_mb << 20,
            cpu_seconds: self.cpu_seconds,
            wall_seconds: self.wall_seconds,
            open_files: self.open_files,
            file_size_bytes: self.file_size_mb << 20,
            remote_deadline_ms: self.remote_deadline_ms,
            remote_frame_bytes: self.remote_frame_mb << 20,
            allow_private_endpoints,
            extra_ca_pem: None,
        })
    }
}

/// `--zoo DIR|none`, shared with `d3il serve` and `d3il tables`.
#[derive(clap::Args, Debug, Clone)]
pub struct ZooArg {
    /// The zoo: a directory of cells `<task>/<method-slug>-s<seed>/`
    /// (default: the assets' `zoo/`), or `none`.
    #[arg(long = "zoo", value_name = "DIR|none")]
    pub zoo: Option<String>,
}

impl ZooArg {
    /// The zoo directory asked for (None: `--zoo none`).
    pub fn dir(&self) -> Option<PathBuf> {
        self.dir_in(&super::assets_dir())
    }

    /// [`ZooArg::dir`] with the assets at `assets`.
    pub fn dir_in(&self, assets: &Path) -> Option<PathBuf> {
        match self.zoo.as_deref() {
            None => Some(assets.join("zoo")),
            Some(s) if s.eq_ignore_ascii_case("none") => None,
            Some(s) => Some(PathBuf::from(s)),
        }
    }
}

/// `--look` of `d3il render` and `d3il bench render`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Look {
    Best,
    Primitives,
    Meshes,
}

impl Look {
    pub fn robot_look(self) -> RobotLook {
        match self {
            Look::Best => best_look(),
            Look::Primitives => RobotLook::Primitives,
            Look::Meshes => RobotLook::Meshes,
        }
    }
}

/// The server configuration `d3il serve` and `d3il workers` share: database
/// and policy store, worker executable, slots, assets and worker limits.
pub fn server_config(
    db: DbArgs,
    bind: SocketAddr,
    worker_exe: Option<PathBuf>,
    workers: Option<usize>,
    assets: Option<PathBuf>,
    limits: &LimitArgs,
    endpoints: &EndpointArgs,
) -> anyhow::Result<d3il_server::app::ServerConfig> {
    let exe = match worker_exe {
        Some(p) => p,
        None => {
            std::env::current_exe().context("cannot find the d3il executable to start workers")?
        }
    };
    let mut cfg = d3il_server::app::ServerConfig::new(db.db, bind, exe);
    cfg.policy_store = db.policy_store;
    if let Some(w) = workers {
        cfg.workers = w;
    }
    if let Some(a) = assets {
        cfg.assets_dir = a;
    }
    anyhow::ensure!(
        cfg.assets_dir.is_dir(),
        "assets directory {} does not exist; pass --assets or set D3IL_ASSETS",
        cfg.assets_dir.display()
    );
    cfg.assets_dir = cfg.assets_dir.canonicalize().unwrap_or(cfg.assets_dir);
    cfg.limits = limits.limits(endpoints.allow_private_endpoints)?;
    cfg.worker.wall_clock = std::time::Duration::from_secs(cfg.limits.wall_seconds + 30);
    Ok(cfg)
}
