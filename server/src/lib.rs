//! d3il-server: the leaderboard service behind `d3il serve`.
//!
//! Dependencies point one way (a test, `tests/app/layout.rs`, refuses cycles):
//!
//! - [`http`] (`api`, `pages`, `plots`; never importing each other) sits on
//!   [`views`] (what the API shows), [`comparison`] (pairing two finished
//!   submissions), [`auth`] (the token extractor) and
//!   [`intake`] (validating and accepting a submission);
//! - those sit on [`state`] (what handlers share), [`queue`] (the worker pool),
//!   [`store`] (SQLite, one module per resource) and [`leaderboard`] (pure
//!   functions: rows, seed aggregation, sorting, figure input);
//! - [`error`] is the HTTP error type and depends only on the store's error;
//!   [`schema`] describes the protocol's types for the OpenAPI document.
//!
//! [`app`] wires it together (router, `serve`); [`cli`], [`client`] and
//! [`ops`] (the store's types the command-line tools use) are what the `d3il`
//! binary calls. [`cache`] keeps finished submissions' results
//! documents in memory; [`linger`] reads on a request body an early answer
//! left unread, so the client gets the answer. [`rollouts`] shows what a
//! policy did (the failure browser's filters, one rollout's record and trace,
//! the pictures drawn from traces) and [`videos`] renders rollout videos
//! through `d3il replay`. [`zoo`] reads the zoo's cells from disk
//! and loads them into the store at start.

#![forbid(unsafe_code)]

pub mod app;
pub mod auth;
pub mod backup;
pub mod board_figures;
pub mod cache;
pub mod canary;
pub mod cancel;
pub mod cli;
pub mod client;
pub mod client_addr;
pub mod comparison;
pub mod config;
pub mod error;
pub mod fidelity;
pub mod http;
pub mod intake;
pub mod leaderboard;
pub mod linger;
pub mod live;
pub mod ops;
pub mod queue;
pub mod quota;
pub mod races;
pub mod ratelimit;
pub mod rollouts;
pub mod runner;
pub mod sandbox_status;
pub mod schema;
pub mod state;
pub mod store;
pub mod telemetry;
pub mod upgrade;
pub mod videos;
pub mod views;
pub mod zoo;
