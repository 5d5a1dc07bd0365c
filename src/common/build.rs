//! This build's identity, recorded in every result's manifest: the git
//! commit it was built from and its physics fingerprint (the drift canary's
//! outcomes hashed). The fingerprint is cached per binary (its sha256) under
//! `$D3IL_CACHE_DIR` (default `$XDG_CACHE_HOME/d3il` or `~/.cache/d3il`), so
//! that `d3il eval`, `d3il serve` and `d3il verify` compute it once per build.

use d3il_evaluator::canary::{self, Outcomes};
use std::path::PathBuf;

fn cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("D3IL_CACHE_DIR") {
        return PathBuf::from(d);
    }
    let base = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .unwrap_or_else(std::env::temp_dir);
    let dir = base.join("d3il");
    // A home without a writable cache (some CI users) falls back to the
    // temporary directory, so the canary still runs once per binary.
    if std::fs::create_dir_all(&dir).is_ok() {
        dir
    } else {
        std::env::temp_dir().join("d3il-cache")
    }
}

/// A cache file of this binary (keyed by the binary's sha256): `<what>-<sha>.<ext>`.
/// None under the drift test's deliberate controller change, whose
/// outcomes are not this build's.
pub fn cache_path(what: &str, ext: &str) -> Option<PathBuf> {
    if std::env::var_os("D3IL_DRIFT_TEST_KP_SCALE").is_some() {
        return None;
    }
    static SHA: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    let sha =
        SHA.get_or_init(|| d3il_server::fidelity::file_sha256(&std::env::current_exe().ok()?).ok());
    let sha = sha.as_deref()?;
    Some(cache_dir().join(format!("{what}-{}.{ext}", &sha[..16])))
}

fn cache_file() -> Option<PathBuf> {
    cache_path("fingerprint", "txt")
}

pub fn store_atomically(f: &std::path::Path, bytes: &[u8]) {
    let _ = std::fs::create_dir_all(f.parent().expect("has a parent"));
    let tmp = f.with_extension(format!("tmp{}", std::process::id()));
    if std::fs::write(&tmp, bytes).is_ok() {
        let _ = std::fs::rename(&tmp, f);
    }
}

pub fn store_cached(fingerprint: &str) {
    if let Some(f) = cache_file() {
        store_atomically(&f, fingerprint.as_bytes());
    }
}

fn cached_fingerprint() -> Option<String> {
    let s = std::fs::read_to_string(cache_file()?).ok()?;
    let s = s.trim();
    (s.len() == 16 && s.bytes().all(|b| b.is_ascii_hexdigit())).then(|| s.to_string())
}

/// An exclusive lock on this binary's canary (a lock file next to its
/// cache), held while one process runs the canary: the test suite and a
/// cluster start many `d3il` processes of a fresh build at once, and
/// without it each would compute the same fingerprint (half a minute of
/// CPU each). None when there is no cache, or the lock cannot be taken:
/// then the canary just runs.
pub fn canary_lock() -> Option<std::fs::File> {
    let f = std::fs::File::create(cache_path("canary", "lock")?).ok()?;
    f.lock().ok()?;
    Some(f)
}

/// This build's physics fingerprint: from the cache, or by running the
/// canary once (about half a minute; said on stderr).
pub fn build_fingerprint() -> anyhow::Result<String> {
    if let Some(fp) = cached_fingerprint() {
        return Ok(fp);
    }
    let _lock = canary_lock();
    if let Some(fp) = cached_fingerprint() {
        return Ok(fp);
    }
    eprintln!("computing this build's physics fingerprint (the drift canary, once per build)...");
    let got: Outcomes = canary::run(&super::assets_dir(), &mut |_| {})?;
    let fp = got.fingerprint();
    store_cached(&fp);
    Ok(fp)
}

/// The git commit this binary was built from (build.rs).
pub const GIT_COMMIT: &str = env!("D3IL_GIT_COMMIT");

/// This build's identity for a result's manifest.
pub fn this_build() -> anyhow::Result<d3il_protocol::BuildIdentity> {
    Ok(d3il_protocol::BuildIdentity {
        git_commit: GIT_COMMIT.to_string(),
        physics_fingerprint: Some(build_fingerprint()?),
    })
}
