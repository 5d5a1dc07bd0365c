//! Tests of the real `d3il serve` binary (d3il_test_support::server: the
//! service on 127.0.0.1 port 0 with a fresh SQLite file, tokens, HTTP helpers): uploads,
//! admin, abuse and secrets, metrics, backups and upgrades, restarts, dry runs,
//! worker hosts, robustness and rollout views. One test binary (each links the
//! whole stack); one module per former test file.

/// The `d3il` binary under test (the server harness starts it, the tests run its other commands).
pub const D3IL: d3il_test_support::server::Binary =
    d3il_test_support::server::Binary(env!("CARGO_BIN_EXE_d3il"));
pub const EXE: &str = D3IL.0;

mod db_support;
#[path = "../robustness_support/mod.rs"]
mod robustness_support;
#[path = "../rollouts_support/mod.rs"]
mod rollouts_support;

mod abuse;
mod db_backup;
mod db_upgrade;
mod endpoint_secret;
mod ops_metrics;
mod robustness_server;
mod robustness_tables;
mod rollouts_e2e;
mod serve_canary;
mod server_admin;
mod server_dry_run;
mod server_e2e;
mod server_restart;
mod server_uploads;
mod worker_hosts;
