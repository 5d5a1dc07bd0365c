//! The server's integration tests, one test binary (each binary links the whole
//! stack, so a few large ones build much faster than one per file): the app
//! in-process on 127.0.0.1 port 0 with a fresh SQLite file or PostgreSQL
//! database (d3il_test_support::server::spawn_app), the store, queue and fair-use limits, pages,
//! plots, snapshots and the module layout. One module per former test file.

mod rollout_support;
#[path = "../../../tables/tests/svg_geometry/mod.rs"]
mod svg_geometry;

mod admin_page;
mod board;
mod build_fingerprints;
mod caching;
mod compare_api;
mod compare_page;
mod hostile;
mod http;
mod layout;
mod limits;
mod metered_races;
mod openapi;
mod plots;
mod queue;
mod queue_slots;
mod quotas_moderation;
mod restore_paths;
mod robustness_coverage;
mod rollout_videos;
mod rollouts_api;
mod snapshots;
mod store;
mod store_shards;
mod zoo;
