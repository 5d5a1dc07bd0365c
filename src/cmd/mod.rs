pub mod bench;
pub mod bench_chaos;
pub mod bench_procs;
pub mod bench_scale;
pub mod bench_scripts;
pub mod bench_serve;
pub mod bench_served_agent;
pub mod bench_video;
pub mod compare;
pub mod contexts;
pub mod db;
pub mod eval;
pub mod fidelity;
pub mod fixtures;
pub mod limits;
pub mod merge;
pub mod render;
pub mod replay;
pub mod serve;
pub mod submit;
pub mod tables;
pub mod token;
pub mod verify;
pub mod worker;
pub mod workers;

/// The assets directory (MJCF, context sets, fixtures): `$D3IL_ASSETS` or the
/// repository's `assets/`.
pub fn assets_dir() -> std::path::PathBuf {
    d3il_server::app::default_assets_dir()
}
