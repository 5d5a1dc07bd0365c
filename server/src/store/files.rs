//! Uploaded policy files in `<data dir>/policies/`: a streamed upload is
//! written to a temporary name and renamed to `<sha256>.onnx` once accepted;
//! temporary files left by a crash are removed at start, and the file of a
//! failed submission is deleted once no live submission uses it (the row
//! keeps its hash and size).

use super::{io_err, Store, StoreError};
use std::path::{Path, PathBuf};

/// Temporary uploads carry this in their name
/// (`upload.onnx.tmp-<place>-<pid>-<n>`, see [`upload_place`]); any such
/// file found at start is debris of an interrupted upload.
pub const TMP_MARKER: &str = ".tmp";

/// Where the pids in temporary upload names mean something: the kernel's
/// boot and the pid namespace of this process (`<boot id, 8 hex>.<pid
/// namespace inode>`). A front end that finds a temporary upload of its own
/// place whose process is gone knows the upload was abandoned (the process
/// was killed mid-upload), however recent it is; one of another place (a
/// machine sharing the policy directory) it cannot judge but by its age.
fn upload_place() -> &'static str {
    static PLACE: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    PLACE.get_or_init(|| {
        let boot = std::fs::read_to_string("/proc/sys/kernel/random/boot_id")
            .map(|b| {
                b.trim()
                    .chars()
                    .filter(char::is_ascii_hexdigit)
                    .take(8)
                    .collect::<String>()
            })
            .unwrap_or_default();
        let ns = std::fs::read_link("/proc/self/ns/pid")
            .map(|l| {
                l.to_string_lossy()
                    .chars()
                    .filter(char::is_ascii_digit)
                    .collect::<String>()
            })
            .unwrap_or_default();
        format!(
            "{}.{}",
            if boot.is_empty() { "noboot" } else { &boot },
            if ns.is_empty() { "0" } else { &ns }
        )
    })
}

/// A temporary upload of this place whose process no longer runs.
fn abandoned_here(name: &str) -> bool {
    let Some((_, rest)) = name.split_once(&format!("{TMP_MARKER}-")) else {
        return false;
    };
    let parts: Vec<&str> = rest.split('-').collect();
    match parts.as_slice() {
        [place, pid, _n] if *place == upload_place() => pid
            .parse::<u32>()
            .is_ok_and(|pid| !Path::new(&format!("/proc/{pid}")).exists()),
        _ => false,
    }
}

/// PostgreSQL advisory lock key of the shared policy directory (any fixed
/// number; "d3il" in ASCII).
const POLICY_FILES_LOCK: i64 = 0x6433_696c;

/// What [`Store::lock_policy_files`] holds: this process's lock and, on
/// PostgreSQL, the transaction holding the advisory lock every front end
/// takes (fields drop in order: the shared lock goes first).
pub struct PolicyFilesGuard<'a> {
    _shared: Option<sqlx::Transaction<'static, sqlx::Postgres>>,
    _local: tokio::sync::MutexGuard<'a, ()>,
}

impl Store {
    /// The directory of uploaded policies.
    pub fn policies_dir(&self) -> PathBuf {
        self.data_dir.join("policies")
    }

    /// A fresh temporary name in the policies directory for a streamed
    /// upload (unique in this process; the place and pid keep processes
    /// apart and tell a later start whether its writer is gone).
    pub fn new_upload_path(&self) -> PathBuf {
        static UPLOADS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = UPLOADS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.policies_dir().join(format!(
            "upload.onnx{TMP_MARKER}-{}-{}-{n}",
            upload_place(),
            std::process::id()
        ))
    }

    /// Moves a complete, synced temporary upload to `<sha256>.onnx`. Returns
    /// the final path and whether this call created it (an identical file
    /// already stored is kept and the temporary removed).
    pub async fn commit_onnx(
        &self,
        tmp: &Path,
        sha256: &str,
    ) -> Result<(PathBuf, bool), StoreError> {
        let path = self.policies_dir().join(format!("{sha256}.onnx"));
        if tokio::fs::try_exists(&path).await.unwrap_or(false) {
            tokio::fs::remove_file(tmp).await.map_err(io_err(tmp))?;
            return Ok((path, false));
        }
        tokio::fs::rename(tmp, &path).await.map_err(io_err(tmp))?;
        Ok((path, true))
    }

    /// Deletes the policy file at `path` unless a submission that is not
    /// failed still uses it. Returns whether it was deleted. Only files in
    /// this store's policies directory are ever deleted.
    pub async fn release_policy_file(&self, path: &str) -> Result<bool, StoreError> {
        // Resolved first (`..`, symlinks): a stored path such as
        // `<policies>/../elsewhere` names a file outside.
        let Some(resolved) = self.in_policies_dir(path) else {
            return Ok(false);
        };
        let _files = self.lock_policy_files().await?;
        let live: i64 = on_db!(&self.db, pool => sqlx::query_scalar(
            "SELECT COUNT(*) FROM submissions WHERE onnx_path = $1 AND status != 'failed'",
        )
        .bind(path)
        .fetch_one(pool)
        .await)?;
        if live > 0 {
            return Ok(false);
        }
        match tokio::fs::remove_file(&resolved).await {
            Ok(()) => Ok(true),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
            Err(e) => Err(io_err(&resolved)(e)),
        }
    }

    /// `path` resolved (`..` and symlinks followed), if it is a file directly
    /// in this store's policies directory; None otherwise (or if it is gone).
    fn in_policies_dir(&self, path: &str) -> Option<PathBuf> {
        let dir = std::fs::canonicalize(self.policies_dir()).ok()?;
        let resolved = std::fs::canonicalize(path).ok()?;
        (resolved.parent() == Some(dir.as_path()) && resolved.is_file()).then_some(resolved)
    }

    /// Holds off [`Store::release_policy_file`] while a policy file is placed
    /// and its submission recorded (release nothing while holding it). On
    /// PostgreSQL the policy directory is shared by every front end, so the
    /// guard also holds a transaction-scoped advisory lock, taken by all of
    /// them; it is released when the guard's transaction ends (dropped,
    /// rolled back).
    pub async fn lock_policy_files(&self) -> Result<PolicyFilesGuard<'_>, StoreError> {
        let local = self.files.lock().await;
        let shared = match &self.db {
            super::Db::Postgres(pool) => {
                let mut tx = pool.begin().await?;
                sqlx::query("SELECT pg_advisory_xact_lock($1)")
                    .bind(POLICY_FILES_LOCK)
                    .execute(&mut *tx)
                    .await?;
                Some(tx)
            }
            _ => None,
        };
        Ok(PolicyFilesGuard {
            _shared: shared,
            _local: local,
        })
    }

    /// Releases the policy file of submission `id` (after it failed).
    pub async fn release_policy_of(&self, id: i64) -> Result<bool, StoreError> {
        let path: Option<String> =
            on_db!(&self.db, pool => sqlx::query_scalar("SELECT onnx_path FROM submissions WHERE id = $1")
                .bind(id)
                .fetch_optional(pool)
                .await)?
                .flatten();
        match path {
            Some(p) => self.release_policy_file(&p).await,
            None => Ok(false),
        }
    }

    /// Bytes of policy files this submitter keeps on disk: distinct files of
    /// their submissions that have not failed.
    pub async fn submitter_disk_bytes(&self, submitter_id: i64) -> Result<u64, StoreError> {
        let n: i64 = on_db!(&self.db, pool => sqlx::query_scalar(
            "SELECT CAST(COALESCE(SUM(b), 0) AS BIGINT) FROM (SELECT MAX(onnx_bytes) AS b FROM submissions \
             WHERE submitter_id = $1 AND status != 'failed' AND onnx_path IS NOT NULL GROUP BY onnx_path) AS files",
        )
        .bind(submitter_id)
        .fetch_one(pool)
        .await)?;
        Ok(n.max(0) as u64)
    }

    /// At start: removes temporary uploads left by a crash, files no
    /// submission refers to, and the files of failed submissions that were
    /// never deleted. Returns how many files
    /// were removed.
    /// On PostgreSQL the directory is shared with other front ends that may
    /// be writing an upload right now: a temporary upload counts as debris
    /// when its writer is known to be gone (a process of this machine that
    /// no longer runs, [`abandoned_here`]) or it is untouched for an hour.
    /// A policy file no submission refers to is debris at once: files are
    /// placed and their submissions recorded under the policy-files lock,
    /// which this holds while it looks.
    pub async fn clean_policy_files(&self) -> Result<usize, StoreError> {
        let dir = self.policies_dir();
        let min_age = std::time::Duration::from_secs(if self.is_postgres() { 3600 } else { 0 });
        let settled = |e: &tokio::fs::DirEntry| {
            let e = e.path();
            async move {
                let modified = tokio::fs::metadata(&e).await.and_then(|m| m.modified());
                modified.is_ok_and(|t| t.elapsed().unwrap_or_default() >= min_age)
            }
        };
        let mut removed = 0;
        let mut entries = tokio::fs::read_dir(&dir).await.map_err(io_err(&dir))?;
        while let Some(e) = entries.next_entry().await.map_err(io_err(&dir))? {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.contains(TMP_MARKER) && (abandoned_here(&name) || settled(&e).await) {
                let p = e.path();
                match tokio::fs::remove_file(&p).await {
                    Ok(()) => removed += 1,
                    Err(err) => tracing::warn!("cannot remove stray upload {}: {err}", p.display()),
                }
            }
        }
        // Files no submission refers to (a crash between storing the file
        // and recording its submission). No upload is between the two while
        // the lock is held.
        let files = self.lock_policy_files().await?;
        let known: std::collections::HashSet<String> =
            on_db!(&self.db, pool => sqlx::query_scalar::<_, String>(
            "SELECT DISTINCT onnx_path FROM submissions WHERE onnx_path IS NOT NULL",
        )
        .fetch_all(pool)
        .await)?
            .into_iter()
            // By file name: a data directory moved with its database still
            // matches its rows.
            .filter_map(|p| {
                Path::new(&p)
                    .file_name()
                    .map(|f| f.to_string_lossy().into_owned())
            })
            .collect();
        let mut entries = tokio::fs::read_dir(&dir).await.map_err(io_err(&dir))?;
        while let Some(e) = entries.next_entry().await.map_err(io_err(&dir))? {
            let p = e.path();
            let orphan = p.extension().is_some_and(|x| x == "onnx")
                && !known.contains(e.file_name().to_string_lossy().as_ref());
            if orphan {
                match tokio::fs::remove_file(&p).await {
                    Ok(()) => removed += 1,
                    Err(err) => tracing::warn!("cannot remove unused {}: {err}", p.display()),
                }
            }
        }
        // Releasing takes the lock itself.
        drop(files);
        let failed: Vec<String> = on_db!(&self.db, pool => sqlx::query_scalar(
            "SELECT DISTINCT onnx_path FROM submissions WHERE status = 'failed' AND onnx_path IS NOT NULL",
        )
        .fetch_all(pool)
        .await)?;
        for p in failed {
            if self.release_policy_file(&p).await? {
                removed += 1;
            }
        }
        if removed > 0 {
            tracing::info!(
                "removed {removed} stray or unused policy file(s) in {}",
                dir.display()
            );
        }
        Ok(removed)
    }
}
