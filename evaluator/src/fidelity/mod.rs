//! The fidelity report (docs/fidelity.md): this simulator against
//! the data recorded in the original D3IL simulator, computed from the
//! project's reference data (`tests/data/`):
//!
//! * [`episodes`]: the recorded episodes replayed open-loop here;
//! * [`closed_loop`]: policies evaluated here against their rollouts there,
//!   and the original's actions of those rollouts replayed here;
//! * [`frames`]: our camera frames of recorded states against the original's;
//! * [`deviations`]: the known deviations and what they can change.
//!
//! The server never runs this: it runs `d3il fidelity --format json` as a
//! subprocess and shows the JSON ([`d3il_protocol::fidelity`]).

pub mod closed_loop;
pub mod deviations;
pub mod episodes;
pub mod frames;

use d3il_protocol::fidelity::{FidelityMode, FidelityReport, FIDELITY_FORMAT};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum FidelityError {
    #[error("reference data {path}: {message}")]
    Data { path: PathBuf, message: String },
    #[error(transparent)]
    Task(#[from] crate::tasks::TaskError),
    #[error(transparent)]
    Eval(#[from] crate::eval::EvalError),
    #[error(transparent)]
    Mujoco(#[from] crate::mujoco::MjError),
    #[error("replaying {what}: {source}")]
    Replay {
        what: String,
        #[source]
        source: crate::open_loop::OpenLoopError,
    },
}

impl FidelityError {
    pub(crate) fn data(path: &Path, message: impl std::fmt::Display) -> Self {
        FidelityError::Data {
            path: path.to_path_buf(),
            message: message.to_string(),
        }
    }
}

/// Where the reference data lives: the directory holding
/// `reference-rollouts/`, `reference-closed-loop/` and `reference-frames/`
/// (the repository's `tests/data`).
#[derive(Debug, Clone)]
pub struct DataDirs {
    pub root: PathBuf,
}

impl DataDirs {
    pub fn rollouts(&self) -> PathBuf {
        self.root.join("reference-rollouts")
    }
    pub fn closed_loop(&self) -> PathBuf {
        self.root.join("reference-closed-loop")
    }
    pub fn frames(&self) -> PathBuf {
        self.root.join("reference-frames")
    }
}

/// Reads and parses a JSON file of the reference data.
pub(crate) fn read_json(path: &Path) -> Result<serde_json::Value, FidelityError> {
    let text = std::fs::read_to_string(path).map_err(|e| FidelityError::data(path, e))?;
    serde_json::from_str(&text).map_err(|e| FidelityError::data(path, e))
}

/// Computes the whole report; `progress` hears what is being done.
pub fn compute(
    data: &DataDirs,
    mode: FidelityMode,
    progress: &mut dyn FnMut(&str),
) -> Result<FidelityReport, FidelityError> {
    let t0 = Instant::now();
    progress("replaying the episodes recorded in the original");
    let episodes = episodes::section(&data.rollouts())?;
    progress("comparing our camera frames with the original's");
    let frames = frames::section(&data.frames())?;
    let closed_loop = closed_loop::section(&data.closed_loop(), mode, progress)?;
    Ok(FidelityReport {
        format: FIDELITY_FORMAT.into(),
        mode,
        d3il_version: env!("CARGO_PKG_VERSION").into(),
        mujoco_version: crate::mujoco::version(),
        generated_unix: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs() as i64)
            .unwrap_or(0),
        seconds: t0.elapsed().as_secs_f64(),
        episodes,
        closed_loop,
        frames,
        deviations: deviations::known(),
    })
}

/// Largest Euclidean distance between corresponding rows (over `n` rows).
pub(crate) fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// A JSON array of numeric rows as f64 rows.
pub(crate) fn rows(
    v: &serde_json::Value,
    path: &Path,
    what: &str,
) -> Result<Vec<Vec<f64>>, FidelityError> {
    let bad = || FidelityError::data(path, format!("`{what}` must be an array of numeric rows"));
    v.as_array()
        .ok_or_else(bad)?
        .iter()
        .map(|r| {
            r.as_array()
                .ok_or_else(bad)?
                .iter()
                .map(|x| x.as_f64().ok_or_else(bad))
                .collect()
        })
        .collect()
}

/// Actions as float32 rows (how the policy produced them).
pub(crate) fn actions(
    v: &serde_json::Value,
    path: &Path,
    what: &str,
) -> Result<Vec<Vec<f32>>, FidelityError> {
    Ok(rows(v, path, what)?
        .into_iter()
        .map(|r| r.into_iter().map(|x| x as f32).collect())
        .collect())
}
