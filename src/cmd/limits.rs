//! The sandbox limits of an evaluation, as flags shared by `d3il serve`,
//! `d3il workers` and `d3il eval` (defined once here; the defaults are
//! `Limits::default()`), and the servers' private-endpoint setting.

use d3il_protocol::Limits;

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
