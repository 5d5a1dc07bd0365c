pub mod bench;
pub mod bench_chaos;
pub mod bench_intervals;
pub mod bench_procs;
pub mod bench_robustness;
pub mod bench_scale;
pub mod bench_scripts;
pub mod bench_sequential;
pub mod bench_serve;
pub mod bench_served_agent;
pub mod bench_video;
pub mod compare;
pub mod contexts;
pub mod db;
pub mod demos;
pub mod eval;
pub mod fidelity;
pub mod fixtures;
pub mod infer;
pub mod intervals;
pub mod limits;
pub mod merge;
pub mod race;
pub mod race_server;
pub mod render;
pub mod replay;
pub mod robustness;
pub mod serve;
pub mod submit;
pub mod tables;
pub mod token;
pub mod verify;
pub mod worker;
pub mod workers;
pub mod zoo;

/// The assets directory (MJCF, context sets, fixtures): `$D3IL_ASSETS` or the
/// repository's `assets/`.
pub fn assets_dir() -> std::path::PathBuf {
    d3il_server::app::default_assets_dir()
}

/// Refuses an output path a command could not write at its end (no such
/// directory, or a directory where the file should go), so that a long run
/// is not lost to a typo: every command checks its outputs before the slow
/// part.
pub fn check_output_path(path: &std::path::Path, flag: &str) -> anyhow::Result<()> {
    if path.is_dir() {
        anyhow::bail!(
            "{flag} {}: is a directory; give a file name",
            path.display()
        );
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => std::path::Path::new("."),
    };
    if !parent.is_dir() {
        anyhow::bail!(
            "{flag} {}: the directory {} does not exist; create it or give another path",
            path.display(),
            parent.display()
        );
    }
    Ok(())
}
