//! What the commands of `d3il` share, and nothing else: a command
//! (`src/cmd/<name>`) uses this module and the library crates, never another
//! command's module, so that a command can be read, moved or deleted on its
//! own. It sits at the crate's root, not under `src/cmd/`, because it is not
//! a command and the benchmarks use it too. It holds only what is the
//! binary's own: the flags several commands take, one evaluation as the
//! command line describes it, this build's identity, and the plain-text form
//! of documents more than one command prints. A rule of the domain itself
//! belongs in a library crate instead.

pub mod build;
pub mod evaluation;
pub mod flags;
pub mod text;

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
