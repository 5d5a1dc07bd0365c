//! The archive: a gzipped tar of `manifest.json`, the database copy
//! (`database.sqlite` or `database.pgdump`) and `policies/<name>` files.

use super::{io_err, BackupError, Inventory};
use crate::fidelity::file_sha256;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Version of the archive layout (a reader refuses others).
pub const FORMAT: u32 = 1;
pub(super) const SQLITE_DB: &str = "database.sqlite";
pub(super) const PG_DUMP: &str = "database.pgdump";
const MANIFEST: &str = "manifest.json";

/// What an archive holds (`manifest.json`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Manifest {
    pub format: u32,
    /// The d3il release that wrote it.
    pub d3il_version: String,
    /// Unix seconds when the copy was taken.
    pub created_at: i64,
    pub postgres: bool,
    /// The latest migration applied in the copy.
    pub schema_version: i64,
    /// Rows per table in the copy.
    pub tables: BTreeMap<String, i64>,
    pub database: PolicyFile,
    /// Where the backed-up store kept its policy files (restore points the
    /// submissions at the new place).
    pub source_policies_dir: String,
    pub policy_files: Vec<PolicyFile>,
    /// Files a live submission of the copy refers to that could not be
    /// archived (deleted since, or outside the policy directory), with why.
    pub missing_policy_files: Vec<String>,
}

/// One file of the archive: its path inside it, size and sha256.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct PolicyFile {
    pub path: String,
    pub bytes: u64,
    pub sha256: String,
}

impl PolicyFile {
    fn of(work: &Path, path: &str) -> Result<PolicyFile, BackupError> {
        let full = work.join(path);
        let bytes = std::fs::metadata(&full).map_err(io_err(&full))?.len();
        let sha256 = file_sha256(&full).map_err(io_err(&full))?;
        Ok(PolicyFile {
            path: path.to_string(),
            bytes,
            sha256,
        })
    }
}

/// A scratch directory next to a given path (same file system, so files
/// move by rename), removed on drop.
pub(super) struct WorkDir(PathBuf);

impl WorkDir {
    pub(super) fn next_to(path: &Path) -> Result<WorkDir, BackupError> {
        let parent = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "d3il".into());
        let dir = parent.join(format!(".{name}.d3il-work-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("policies")).map_err(io_err(&dir))?;
        Ok(WorkDir(dir))
    }

    pub(super) fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for WorkDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Collects the policy files `inv` refers to, writes the manifest and the
/// archive `out` (through a temporary name, synced, then renamed).
pub(super) fn write(
    out: &Path,
    work: &WorkDir,
    db_file: &Path,
    inv: &Inventory,
    postgres: bool,
    data_dir: &Path,
) -> Result<Manifest, BackupError> {
    let policies = data_dir.join("policies");
    let mut files = vec![];
    let mut missing = vec![];
    for p in &inv.policy_paths {
        let path = Path::new(&p.path);
        let name = match path.parent() {
            Some(parent) if parent == policies => path.file_name().map(|n| n.to_string_lossy()),
            _ => None,
        };
        let Some(name) = name else {
            if p.live {
                missing.push(format!(
                    "{}: outside the policy directory {}",
                    p.path,
                    policies.display()
                ));
            }
            continue;
        };
        let rel = format!("policies/{name}");
        let dest = work.path().join(&rel);
        // A hard link keeps the file even if the server deletes it meanwhile.
        let linked =
            std::fs::hard_link(path, &dest).or_else(|_| std::fs::copy(path, &dest).map(|_| ()));
        match linked {
            Ok(()) => files.push(PolicyFile::of(work.path(), &rel)?),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                if p.live {
                    missing.push(format!("{}: no such file", p.path));
                }
            }
            Err(e) => return Err(io_err(path)(e)),
        }
    }
    let db_name = db_file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let manifest = Manifest {
        format: FORMAT,
        d3il_version: env!("CARGO_PKG_VERSION").to_string(),
        created_at: crate::store::now(),
        postgres,
        schema_version: inv.schema_version,
        tables: inv.tables.clone(),
        database: PolicyFile::of(work.path(), &db_name)?,
        source_policies_dir: policies.to_string_lossy().into_owned(),
        policy_files: files,
        missing_policy_files: missing,
    };
    let json = serde_json::to_vec_pretty(&manifest).expect("the manifest serialises");
    std::fs::write(work.path().join(MANIFEST), json).map_err(io_err(work.path()))?;

    let mut tmp = out.as_os_str().to_owned();
    tmp.push(".partial");
    let tmp = PathBuf::from(tmp);
    let file = std::fs::File::create(&tmp).map_err(io_err(&tmp))?;
    let gz = flate2::write::GzEncoder::new(file, flate2::Compression::fast());
    let mut tar = tar::Builder::new(gz);
    let mut names = vec![MANIFEST.to_string(), db_name];
    names.extend(manifest.policy_files.iter().map(|f| f.path.clone()));
    for name in &names {
        let src = work.path().join(name);
        tar.append_path_with_name(&src, name)
            .map_err(io_err(&src))?;
    }
    let file = tar
        .into_inner()
        .and_then(|gz| gz.finish())
        .map_err(io_err(&tmp))?;
    file.sync_all().map_err(io_err(&tmp))?;
    std::fs::rename(&tmp, out).map_err(io_err(out))?;
    Ok(manifest)
}

/// The largest manifest read (it lists every policy file: a few hundred
/// bytes each).
const MAX_MANIFEST_BYTES: u64 = 64 << 20;

/// A name the archive may hold: the manifest, a database copy, or a plain
/// file name under `policies/`.
fn allowed(name: &str) -> bool {
    match name.strip_prefix("policies/") {
        Some(file) => {
            !file.is_empty()
                && !file.contains('/')
                && file != ".."
                && file != "."
                && !file.contains('\0')
        }
        None => [MANIFEST, SQLITE_DB, PG_DUMP].contains(&name),
    }
}

/// Unpacks `input` into `work` and checks every file against the manifest
/// (size and sha256; nothing missing, nothing extra).
pub(super) fn unpack_and_verify(input: &Path, work: &WorkDir) -> Result<Manifest, BackupError> {
    let not_backup = |why: String| {
        BackupError::Refused(format!(
            "{} is not a d3il backup archive ({why}); give a file `d3il db backup --out` wrote",
            input.display()
        ))
    };
    let file = std::fs::File::open(input).map_err(io_err(input))?;
    let mut archive = tar::Archive::new(flate2::read::GzDecoder::new(file));
    let mut seen = vec![];
    // The manifest comes first (`write`); every later entry is unpacked only
    // up to the size the manifest declares for it, so an archive cannot
    // fill the disk before it is found out.
    let mut declared: Option<Manifest> = None;
    for entry in archive.entries().map_err(|e| not_backup(e.to_string()))? {
        let mut entry = entry.map_err(|e| not_backup(e.to_string()))?;
        let name = entry
            .path()
            .map_err(|e| not_backup(e.to_string()))?
            .to_string_lossy()
            .into_owned();
        if !allowed(&name) || !entry.header().entry_type().is_file() {
            return Err(not_backup(format!("unexpected entry `{name}`")));
        }
        let size = entry
            .header()
            .size()
            .map_err(|e| not_backup(e.to_string()))?;
        let cap = match (&declared, name.as_str()) {
            (_, MANIFEST) => MAX_MANIFEST_BYTES,
            (None, _) => return Err(not_backup(format!("`{name}` comes before manifest.json"))),
            (Some(m), _) => std::iter::once(&m.database)
                .chain(&m.policy_files)
                .find(|f| f.path == name)
                .map(|f| f.bytes)
                .ok_or_else(|| not_backup(format!("`{name}` is not in its manifest")))?,
        };
        if size > cap {
            return Err(BackupError::Refused(format!(
                "{}: `{name}` is {size} bytes and {}; nothing was restored",
                input.display(),
                if name == MANIFEST {
                    format!("a manifest is at most {MAX_MANIFEST_BYTES}")
                } else {
                    format!("the manifest says {cap}")
                }
            )));
        }
        // Written as the store writes its own files (its modes, not the
        // archive's), and never past the size declared.
        let dest = work.path().join(&name);
        let mut out = std::fs::File::create(&dest).map_err(io_err(&dest))?;
        std::io::copy(&mut std::io::Read::take(&mut entry, cap), &mut out)
            .map_err(io_err(&dest))?;
        if name == MANIFEST {
            let text = std::fs::read(&dest).map_err(io_err(&dest))?;
            declared = Some(
                serde_json::from_slice(&text)
                    .map_err(|e| not_backup(format!("manifest.json: {e}")))?,
            );
        }
        seen.push(name);
    }
    let text = std::fs::read(work.path().join(MANIFEST))
        .map_err(|_| not_backup("no manifest.json".into()))?;
    let manifest: Manifest =
        serde_json::from_slice(&text).map_err(|e| not_backup(format!("manifest.json: {e}")))?;
    if manifest.format != FORMAT {
        return Err(BackupError::Refused(format!(
            "{} has archive format {} and this d3il reads format {FORMAT}: restore it with d3il {}",
            input.display(),
            manifest.format,
            manifest.d3il_version
        )));
    }
    let mut expected: Vec<&PolicyFile> = vec![&manifest.database];
    expected.extend(&manifest.policy_files);
    let mut problems = vec![];
    for f in &expected {
        if !allowed(&f.path) || !seen.contains(&f.path) {
            problems.push(format!("{} is missing", f.path));
            continue;
        }
        let got = PolicyFile::of(work.path(), &f.path)?;
        if got != **f {
            problems.push(format!(
                "{}: {} bytes with sha256 {}, the manifest says {} bytes with sha256 {}",
                f.path, got.bytes, got.sha256, f.bytes, f.sha256
            ));
        }
    }
    for name in &seen {
        if name != MANIFEST && !expected.iter().any(|f| &f.path == name) {
            problems.push(format!("{name} is not in the manifest"));
        }
    }
    if !problems.is_empty() {
        return Err(BackupError::Refused(format!(
            "{} does not match its manifest, nothing was restored: {}",
            input.display(),
            problems.join("; ")
        )));
    }
    Ok(manifest)
}

/// Refuses a policy directory that already holds files, unless `force`.
pub(super) fn check_policy_dir_empty(policies: &Path, force: bool) -> Result<(), BackupError> {
    let n = std::fs::read_dir(policies)
        .map(|d| d.flatten().count())
        .unwrap_or(0);
    if n > 0 && !force {
        return Err(BackupError::Refused(format!(
            "the policy directory {} already holds {n} file(s); restore into an empty store (another \
             --policy-store, or a --db file in another directory), or add --force to add to it",
            policies.display()
        )));
    }
    Ok(())
}

/// Moves the archive's policy files into `policies`; returns how many.
pub(super) fn place_policy_files(
    work: &WorkDir,
    manifest: &Manifest,
    policies: &Path,
) -> Result<usize, BackupError> {
    std::fs::create_dir_all(policies).map_err(io_err(policies))?;
    for f in &manifest.policy_files {
        let src = work.path().join(&f.path);
        let name = f.path.trim_start_matches("policies/");
        let dest = policies.join(name);
        if std::fs::rename(&src, &dest).is_err() {
            std::fs::copy(&src, &dest).map_err(io_err(&dest))?;
        }
    }
    Ok(manifest.policy_files.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    /// An archive of a manifest declaring `declared` bytes for its database
    /// and a database entry of `actual` bytes with mode `mode`.
    fn archive(dir: &Path, declared: u64, actual: usize, mode: u32) -> PathBuf {
        let db = vec![7u8; actual];
        let manifest = Manifest {
            format: FORMAT,
            d3il_version: "test".into(),
            created_at: 0,
            postgres: false,
            schema_version: 1,
            tables: BTreeMap::new(),
            database: PolicyFile {
                path: SQLITE_DB.into(),
                bytes: declared,
                sha256: hex::encode(<sha2::Sha256 as sha2::Digest>::digest(&db)),
            },
            source_policies_dir: "/nowhere".into(),
            policy_files: vec![],
            missing_policy_files: vec![],
        };
        let path = dir.join("a.tar.gz");
        let gz = flate2::write::GzEncoder::new(
            std::fs::File::create(&path).unwrap(),
            flate2::Compression::fast(),
        );
        let mut tar = tar::Builder::new(gz);
        for (name, bytes, mode) in [
            (MANIFEST, serde_json::to_vec(&manifest).unwrap(), 0o644),
            (SQLITE_DB, db, mode),
        ] {
            let mut h = tar::Header::new_gnu();
            h.set_size(bytes.len() as u64);
            h.set_mode(mode);
            h.set_cksum();
            tar.append_data(&mut h, name, bytes.as_slice()).unwrap();
        }
        tar.into_inner().unwrap().finish().unwrap();
        path
    }

    /// An entry larger than its manifest says is refused before
    /// more than the declared bytes are written, and unpacked files get the
    /// store's modes, not the archive's (no setuid, no world write).
    #[test]
    fn entries_are_capped_at_their_declared_size_and_get_the_stores_modes() {
        let dir = tempfile::tempdir().unwrap();
        let big = archive(dir.path(), 10, 1 << 20, 0o644);
        let work = WorkDir::next_to(&dir.path().join("big.sqlite")).unwrap();
        let e = unpack_and_verify(&big, &work).unwrap_err().to_string();
        assert!(
            e.contains("is 1048576 bytes and the manifest says 10"),
            "{e}"
        );
        let written = std::fs::metadata(work.path().join(SQLITE_DB)).map_or(0, |m| m.len());
        assert_eq!(written, 0, "nothing of it was unpacked");

        let ok = archive(dir.path(), 100, 100, 0o6777);
        let work = WorkDir::next_to(&dir.path().join("ok.sqlite")).unwrap();
        unpack_and_verify(&ok, &work).unwrap();
        let mode = std::fs::metadata(work.path().join(SQLITE_DB))
            .unwrap()
            .permissions()
            .mode();
        assert_eq!(mode & 0o7000, 0, "no setuid/setgid/sticky: {mode:o}");
        assert_eq!(mode & 0o002, 0, "not world-writable: {mode:o}");
    }
}
