//! d3il-server: the leaderboard service behind `d3il serve` (issue 7).
//!
//! - [`store`]: SQLite schema, paper results, submissions, durable job queue, results.
//! - [`queue`]: worker pool leasing jobs and running them through a [`queue::JobRunner`].
//! - [`app`]: configuration, router and `serve`; [`pages`], [`api`], [`plot_routes`]: HTTP.
//! - [`client`]: the blocking HTTP client behind `d3il submit`.

pub mod api;
pub mod app;
pub mod cli;
pub mod client;
pub mod error;
pub mod intake;
pub mod pages;
pub mod plot_routes;
pub mod plots;
pub mod queue;
pub mod ratelimit;
pub mod runner;
pub mod sandbox_status;
pub mod stats;
pub mod store;
