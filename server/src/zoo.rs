//! The zoo: the paper's methods trained here with the D3IL
//! reference code on demonstrations recorded from our tasks, shipped under
//! `assets/zoo/<task>/<method-slug>-s<seed>/` (`policy.onnx`, `policy.json`,
//! `result.json` made by `d3il eval --protocol paper --json`, and
//! `provenance.json`). Every start reads the cells, checks the sha256s the
//! provenance lists against the files (a mismatch skips the cell with a log
//! line; the start goes on) and stores each as a finished submission of the
//! `zoo` submitter ([`crate::store::Store::load_zoo_cell`]), marked with its
//! data source. `d3il zoo reeval` reads the same cells ([`read_zoo`]).

use crate::leaderboard::BoardRow;
use crate::store::{NewZooCell, Store, StoreError, ZooLoad};
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::{EvalResult, PolicyManifest, TaskId};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The zoo's stated size budget: the bytes of every file under the shipped
/// zoo (assets/zoo), what a clone carries (docs/zoo.md, "Size"). Git keeps
/// every replaced cell's blobs besides, so the repository grows faster.
/// `d3il zoo check` refuses a zoo over it.
pub const SIZE_BUDGET_BYTES: u64 = 110_000_000;

/// The bytes of every file under `zoo`, its subdirectories included.
pub fn size_bytes(zoo: &Path) -> std::io::Result<u64> {
    let mut total = 0;
    for e in std::fs::read_dir(zoo)? {
        let e = e?;
        let t = e.file_type()?;
        if t.is_dir() {
            total += size_bytes(&e.path())?;
        } else if t.is_file() {
            total += e.metadata()?.len();
        }
    }
    Ok(total)
}

/// The files of a cell, as the provenance's `sha256` map names them. The
/// ONNX, the result and the policy manifest must be there; the training
/// files (checkpoint, scaler, config) are checked when they are shipped.
const HASHED_FILES: [(&str, &str, bool); 7] = [
    ("onnx", "policy.onnx", true),
    ("result", "result.json", true),
    ("manifest", "policy.json", true),
    ("checkpoint", "checkpoint.pt", false),
    ("scaler", "scaler.npz", false),
    ("config", "config.yaml", false),
    // The robustness suite's document (`scripts/zoo/suites.py`), when run.
    ("robustness", "robustness.json", false),
];

/// The fields of `provenance.json` the service reads; everything else is
/// kept as shipped and shown as it is.
#[derive(Debug, Clone, serde::Deserialize)]
pub struct Provenance {
    pub zoo_version: String,
    pub task: TaskId,
    /// The paper's method name (`BC-MLP`).
    pub method: String,
    pub seed: i64,
    /// `false` while the training command is still writing the cell.
    #[serde(default)]
    pub complete: Option<bool>,
    pub demos: Demos,
    /// File kind (`onnx`, `result`, `checkpoint`, ...) -> sha256.
    pub sha256: BTreeMap<String, String>,
}

#[derive(Debug, Clone, serde::Deserialize)]
pub struct Demos {
    /// The demonstrations' version (`v1`): the rows say "trained here on
    /// d3il demos v1".
    pub version: String,
}

/// A zoo cell read from disk and checked.
#[derive(Debug)]
pub struct ZooCell {
    /// `<task>/<dir>`.
    pub name: String,
    pub dir: PathBuf,
    pub provenance: Provenance,
    pub provenance_json: String,
    pub result: EvalResult,
    pub result_sha256: String,
    pub manifest_json: String,
    pub onnx_sha256: String,
    pub onnx_bytes: i64,
    /// `robustness.json` (`d3il eval --suite robustness --json`), when the
    /// cell has one: the task's Robustness view shows it.
    pub robustness: Option<RobustnessResult>,
}

/// Why a cell is skipped.
#[derive(Debug, thiserror::Error)]
pub enum ZooError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} is not valid: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error(
        "{path}: sha256 {actual} is not the {expected} its provenance.json lists (the file was changed after the \
         record was made; regenerate the cell or restore the file)"
    )]
    Tampered {
        path: PathBuf,
        expected: String,
        actual: String,
    },
}

/// What the data-source mark of a row trained on demos `version` says.
pub fn data_source(version: &str) -> String {
    format!("trained here on d3il demos {version}")
}

/// Drift: a zoo row whose result was made by a build other than
/// the one with the `current` physics fingerprint, and why; None when it is
/// this build's, when this build's fingerprint is not known yet, or for rows
/// that are not the zoo's.
pub fn drift_note(row: &BoardRow, current: Option<&str>) -> Option<String> {
    row.data_source.as_ref()?;
    current?;
    if row.physics_fingerprint.as_deref() == current {
        return None;
    }
    row.build_note(current)
}

/// Where a cell keeps `file`: the file itself, or, for the two JSON
/// documents (result, robustness), `file.gz` when only that is shipped. The
/// zoo gzips them (`scripts/zoo/pack.py`): a paper-protocol result with its
/// rollout records is 2–7 MB of JSON and about a fifth of that gzipped. The
/// provenance's sha256 is the shipped file's.
pub fn shipped(dir: &Path, file: &str) -> PathBuf {
    let plain = dir.join(file);
    let gz = dir.join(format!("{file}.gz"));
    if !plain.exists() && file.ends_with(".json") && gz.exists() {
        gz
    } else {
        plain
    }
}

/// The JSON text of a cell document read from `path`: gunzipped when it is
/// the `.gz` form ([`shipped`]).
fn unpacked(path: &Path, bytes: Vec<u8>) -> Result<Vec<u8>, ZooError> {
    if path.extension().is_none_or(|e| e != "gz") {
        return Ok(bytes);
    }
    use std::io::Read;
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(bytes.as_slice())
        .read_to_end(&mut out)
        .map_err(|e| invalid(path, format!("not a gzip file: {e}")))?;
    Ok(out)
}

/// A cell document's JSON text (`result.json` or `robustness.json`, gzipped
/// or not), for the commands that read one outside the loader.
pub fn read_document(dir: &Path, file: &str) -> Result<Vec<u8>, ZooError> {
    let path = shipped(dir, file);
    let (_, bytes) = sha256_file(&path)?;
    unpacked(&path, bytes)
}

fn sha256_file(path: &Path) -> Result<(String, Vec<u8>), ZooError> {
    let bytes = std::fs::read(path).map_err(|source| ZooError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    Ok((hex::encode(Sha256::digest(&bytes)), bytes))
}

fn invalid(path: &Path, message: impl Into<String>) -> ZooError {
    ZooError::Invalid {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Reads and checks one cell directory (`<zoo>/<task>/<dir>`).
pub fn read_cell(dir: &Path) -> Result<ZooCell, ZooError> {
    let name = format!(
        "{}/{}",
        dir.parent()
            .and_then(|p| p.file_name())
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        dir.file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    );
    let ppath = dir.join("provenance.json");
    let (_, pbytes) = sha256_file(&ppath)?;
    let provenance_json = String::from_utf8(pbytes).map_err(|_| invalid(&ppath, "not UTF-8"))?;
    let provenance: Provenance =
        serde_json::from_str(&provenance_json).map_err(|e| invalid(&ppath, e.to_string()))?;
    for required in ["onnx", "result"] {
        if !provenance.sha256.contains_key(required) {
            return Err(invalid(
                &ppath,
                format!("`sha256.{required}` is missing: every cell's ONNX and result are hashed"),
            ));
        }
    }
    let mut files: BTreeMap<&str, (String, Vec<u8>)> = BTreeMap::new();
    if provenance.complete == Some(false) {
        return Err(invalid(&ppath, "the record says the cell is not complete"));
    }
    for (kind, file, required) in HASHED_FILES {
        let path = shipped(dir, file);
        let Some(expected) = provenance.sha256.get(kind) else {
            continue;
        };
        if !required && !path.exists() {
            continue;
        }
        let (actual, bytes) = sha256_file(&path)?;
        if !actual.eq_ignore_ascii_case(expected) {
            return Err(ZooError::Tampered {
                path,
                expected: expected.clone(),
                actual,
            });
        }
        let bytes = unpacked(&path, bytes)?;
        files.insert(kind, (actual, bytes));
    }
    let robustness = match files.remove("robustness") {
        None => None,
        Some((_, bytes)) => {
            let path = shipped(dir, "robustness.json");
            let doc: RobustnessResult =
                serde_json::from_slice(&bytes).map_err(|e| invalid(&path, e.to_string()))?;
            if doc.task != provenance.task {
                return Err(invalid(
                    &path,
                    format!("its task is {}, the cell's {}", doc.task, provenance.task),
                ));
            }
            Some(doc)
        }
    };
    let (result_sha256, rbytes) = files.remove("result").unwrap_or_default();
    let (onnx_sha256, obytes) = files.remove("onnx").unwrap_or_default();
    let rpath = shipped(dir, "result.json");
    let result: EvalResult =
        serde_json::from_slice(&rbytes).map_err(|e| invalid(&rpath, e.to_string()))?;
    let mpath = dir.join("policy.json");
    let manifest_json = std::fs::read_to_string(&mpath).map_err(|source| ZooError::Io {
        path: mpath.clone(),
        source,
    })?;
    let manifest: PolicyManifest =
        serde_json::from_str(&manifest_json).map_err(|e| invalid(&mpath, e.to_string()))?;
    let task_dir = name.split('/').next().unwrap_or("");
    if provenance.task.slug() != task_dir
        || result.manifest.task != provenance.task
        || manifest.task != provenance.task
    {
        return Err(invalid(
            &ppath,
            format!(
                "task {} does not match the directory `{task_dir}`, the result's {} or the policy manifest's {}",
                provenance.task, result.manifest.task, manifest.task
            ),
        ));
    }
    if !result
        .manifest
        .policy_sha256
        .eq_ignore_ascii_case(&onnx_sha256)
    {
        return Err(invalid(
            &rpath,
            format!(
                "it evaluated the policy with sha256 {}, not this cell's policy.onnx ({onnx_sha256})",
                result.manifest.policy_sha256
            ),
        ));
    }
    Ok(ZooCell {
        name,
        dir: dir.to_path_buf(),
        provenance,
        provenance_json,
        result,
        result_sha256,
        manifest_json,
        onnx_sha256,
        onnx_bytes: obytes.len() as i64,
        robustness,
    })
}

/// The cell directories of the zoo at `zoo` (`<task>/<dir>/` holding a
/// `provenance.json`), in name order; none when `zoo` does not exist.
pub fn cell_dirs(zoo: &Path) -> Vec<PathBuf> {
    let sorted = |dir: &Path| -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
            .map(|rd| {
                rd.flatten()
                    .map(|e| e.path())
                    .filter(|p| p.is_dir())
                    .collect()
            })
            .unwrap_or_default();
        v.sort();
        v
    };
    sorted(zoo)
        .iter()
        .flat_map(|task| sorted(task))
        // A cell being written (`.<dir>.tmp`) is not one yet.
        .filter(|cell| {
            !cell
                .file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with('.'))
                && cell.join("provenance.json").is_file()
        })
        .collect()
}

/// Every cell of the zoo at `zoo`, read and checked (a cell that fails its
/// checks is an error of its own; the others are unaffected).
pub fn read_zoo(zoo: &Path) -> Vec<(PathBuf, Result<ZooCell, ZooError>)> {
    cell_dirs(zoo)
        .into_iter()
        .map(|d| {
            let r = read_cell(&d);
            (d, r)
        })
        .collect()
}

/// What a start made of the zoo.
#[derive(Debug, Default)]
pub struct ZooReport {
    pub loaded: Vec<(String, ZooLoad)>,
    /// Cell directory and why it was skipped.
    pub skipped: Vec<(PathBuf, String)>,
}

impl ZooReport {
    /// The submissions whose result was replaced by a cell's new one.
    pub fn replaced(&self) -> impl Iterator<Item = i64> + '_ {
        self.loaded.iter().filter_map(|(_, l)| match l {
            ZooLoad::Replaced(id) => Some(*id),
            _ => None,
        })
    }
}

/// Loads every cell of the zoo at `zoo` into `store` (at every start; see
/// the module docs). A cell that fails its checks, or that the store
/// refuses, is skipped with a log line; only a store that cannot be written
/// at all is an error.
pub async fn load(store: &Store, zoo: &Path) -> Result<ZooReport, StoreError> {
    let mut report = ZooReport::default();
    let dir = zoo.to_path_buf();
    let cells = tokio::task::spawn_blocking(move || cell_dirs(&dir))
        .await
        .unwrap_or_default();
    if cells.is_empty() {
        tracing::info!("zoo: no cells under {}", zoo.display());
        return Ok(report);
    }
    for dir in cells {
        let d = dir.clone();
        let cell = match tokio::task::spawn_blocking(move || read_cell(&d)).await {
            Ok(Ok(c)) => c,
            Ok(Err(e)) => {
                tracing::warn!("zoo cell {} skipped: {e}", dir.display());
                report.skipped.push((dir, e.to_string()));
                continue;
            }
            Err(e) => {
                report.skipped.push((dir, e.to_string()));
                continue;
            }
        };
        let new = NewZooCell {
            cell: cell.name.clone(),
            method: cell.provenance.method.clone(),
            training_seed: cell.provenance.seed,
            data_source: data_source(&cell.provenance.demos.version),
            result_sha256: cell.result_sha256,
            manifest_json: cell.manifest_json,
            onnx: cell.dir.join("policy.onnx"),
            onnx_sha256: cell.onnx_sha256,
            onnx_bytes: cell.onnx_bytes,
            provenance_json: cell.provenance_json,
            result: cell.result,
            robustness: cell.robustness,
        };
        match store.load_zoo_cell(&new).await {
            Ok(l) => report.loaded.push((new.cell, l)),
            Err(e @ (StoreError::Conflict(_) | StoreError::Io { .. })) => {
                tracing::warn!("zoo cell {} skipped: {e}", dir.display());
                report.skipped.push((dir, e.to_string()));
            }
            Err(e) => return Err(e),
        }
    }
    let changed = report
        .loaded
        .iter()
        .filter(|(_, l)| !matches!(l, ZooLoad::Unchanged(_)))
        .count();
    tracing::info!(
        "zoo {}: {} cells on the board ({changed} loaded now), {} skipped",
        zoo.display(),
        report.loaded.len(),
        report.skipped.len()
    );
    Ok(report)
}

/// A zoo submission's provenance as the API and its page show it.
#[derive(Debug, Clone, serde::Serialize, utoipa::ToSchema)]
pub struct ProvenanceView {
    pub submission_id: i64,
    /// The cell's directory under the zoo (`aligning/bc-mlp-s0`).
    pub cell: String,
    pub method: String,
    pub task: String,
    pub training_seed: i64,
    /// "trained here on d3il demos v1".
    pub data_source: String,
    /// sha256 of the `result.json` loaded, and when (unix seconds).
    pub result_sha256: String,
    pub loaded_at: i64,
    /// The physics fingerprint of the build that made the result.
    pub physics_fingerprint: Option<String>,
    /// This server's physics fingerprint (null until its canary has run,
    /// or when it does not run it).
    pub this_build: Option<String>,
    /// Why the result may have moved: it was made by another build (null:
    /// the same build, or this build's fingerprint is not known).
    pub drift: Option<String>,
    /// `provenance.json` as shipped with the cell.
    #[schema(value_type = Object)]
    pub provenance: serde_json::Value,
}

/// The provenance of submission `id` (None: not one of the zoo's), shown by
/// the build with the `current` physics fingerprint.
pub async fn provenance_view(
    store: &Store,
    id: i64,
    current: Option<&str>,
) -> Result<Option<ProvenanceView>, StoreError> {
    let Some(cell) = store.zoo_cell_of(id).await? else {
        return Ok(None);
    };
    let s = store.submission(id).await?;
    let fingerprint = store
        .result_for(id)
        .await?
        .and_then(|r| r.manifest())
        .and_then(|m| m.build)
        .and_then(|b| b.physics_fingerprint);
    let drift = match (&fingerprint, current) {
        (Some(f), Some(c)) if f == c => None,
        (_, None) => None,
        (f, c) => crate::leaderboard::other_build_note(f.as_deref(), c),
    };
    Ok(Some(ProvenanceView {
        submission_id: id,
        provenance: cell.provenance(),
        cell: cell.cell,
        method: s.method,
        task: s.task.slug().to_string(),
        training_seed: s.training_seed,
        data_source: s.data_source.unwrap_or_default(),
        result_sha256: cell.result_sha256,
        loaded_at: cell.loaded_at,
        physics_fingerprint: fingerprint,
        this_build: current.map(str::to_string),
        drift,
    }))
}

/// The zoo's rows for `d3il tables --table zoo`: every board row with a
/// data source, by task (in the paper's order) and method.
pub async fn table_rows(store: &Store) -> Result<Vec<d3il_tables::zoo::ZooRow>, StoreError> {
    let mut rows: Vec<BoardRow> = store
        .board_rows()
        .await?
        .into_iter()
        .filter(|r| r.data_source.is_some())
        .collect();
    let order = |r: &BoardRow| TaskId::ALL.iter().position(|t| Some(*t) == r.task);
    rows.sort_by(|a, b| {
        (order(a), &a.task_title, &a.method).cmp(&(order(b), &b.task_title, &b.method))
    });
    Ok(rows
        .into_iter()
        .map(|r| d3il_tables::zoo::ZooRow {
            task: r.task_title,
            method: r.method,
            data_source: r.data_source.unwrap_or_default(),
            protocol: r
                .protocol
                .map(|p| p.as_str().to_string())
                .unwrap_or_default(),
            initial_states: r.initial_states.unwrap_or_default(),
            success: r.success,
            entropy: r.entropy,
            behaviour: r.behaviour_entropy,
            n_seeds: r.n_seeds,
            physics_fingerprint: r.physics_fingerprint,
        })
        .collect())
}
