//! The `suite` field of a submission (issue 40, docs/robustness.md): the
//! one suite name, and whether a task and observation type have a suite.

use super::{opt, RawSubmission};
use crate::error::AppError;
use d3il_protocol::{ObsType, TaskId};

/// The one suite a submission can ask for (docs/robustness.md).
pub const SUITE: &str = "robustness";

pub(super) fn suite_field(raw: &RawSubmission) -> Result<Option<String>, AppError> {
    match opt(raw, "suite") {
        None => Ok(None),
        Some(s) if s == SUITE => Ok(Some(s)),
        Some(s) => Err(AppError::invalid(
            "suite",
            format!("`suite` is `{s}`; the one suite is `{SUITE}` (or leave it out for a plain evaluation)"),
        )),
    }
}

/// Whether `task` with `obs` observations has a robustness suite: a suite
/// file in `assets/robustness/`, `<task>-v<N>.json` for state policies and
/// `<task>-image-v<N>.json` for image policies (the worker's
/// `d3il_evaluator::robustness::suite_for` checks the same, with the files'
/// sha256, before it evaluates).
pub fn check_suite_available(
    assets_dir: &std::path::Path,
    task: TaskId,
    obs: ObsType,
) -> Result<(), AppError> {
    let dir = assets_dir.join("robustness");
    let prefix = |t: TaskId, o: ObsType| match o {
        ObsType::State => format!("{}-v", t.slug()),
        ObsType::Image => format!("{}-image-v", t.slug()),
    };
    let has = |t: TaskId, o: ObsType| {
        std::fs::read_dir(&dir).is_ok_and(|entries| {
            entries.flatten().any(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                name.starts_with(&prefix(t, o)) && name.ends_with(".json")
            })
        })
    };
    if has(task, obs) {
        return Ok(());
    }
    let names = [ObsType::State, ObsType::Image]
        .into_iter()
        .map(|o| {
            let tasks: Vec<&str> = TaskId::ALL
                .iter()
                .filter(|&&t| has(t, o))
                .map(|t| t.slug())
                .collect();
            format!("{} observations: {}", o.as_str(), tasks.join(", "))
        })
        .collect::<Vec<_>>()
        .join("; ");
    Err(AppError::invalid(
        "suite",
        format!("task `{task}` has no robustness suite for {obs} observations yet; suites exist for {names}; leave `suite` out for a plain evaluation"),
    ))
}

/// How many evaluations a suite job of `task` with `obs` observations runs:
/// level 0 and every level of the task's current suite file in
/// `assets_dir/robustness/` (the newest `<task>-v<N>.json`, or
/// `<task>-image-v<N>.json` for image policies). None without a readable
/// suite file.
pub fn suite_evaluations(
    assets_dir: &std::path::Path,
    task: TaskId,
    obs: ObsType,
) -> Option<usize> {
    let prefix = match obs {
        ObsType::State => format!("{}-v", task.slug()),
        ObsType::Image => format!("{}-image-v", task.slug()),
    };
    let newest = std::fs::read_dir(assets_dir.join("robustness"))
        .ok()?
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let v: u32 = name
                .strip_prefix(&prefix)?
                .strip_suffix(".json")?
                .parse()
                .ok()?;
            Some((v, e.path()))
        })
        .max_by_key(|(v, _)| *v)?;
    let file: serde_json::Value = serde_json::from_slice(&std::fs::read(newest.1).ok()?).ok()?;
    let levels: usize = file["axes"]
        .as_array()?
        .iter()
        .map(|a| a["levels"].as_array().map_or(0, Vec::len))
        .sum();
    Some(1 + levels)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every task has a state suite in the repository's assets, so a
    /// submission with `suite=robustness` is accepted for each, with its
    /// number of evaluations (level 0 and every level of the file); an
    /// image variant without an image suite (Stacking's) is refused, the
    /// message listing the tasks that have one.
    #[test]
    fn every_task_has_a_state_suite_and_stackings_image_variant_none() {
        let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        for task in TaskId::ALL {
            check_suite_available(&assets, task, ObsType::State).unwrap();
            let n = suite_evaluations(&assets, task, ObsType::State).unwrap();
            // Avoiding: noise and latency, three levels each; the others
            // at least four axes of three levels.
            assert!(
                if task == TaskId::Avoiding {
                    n == 7
                } else {
                    n >= 13
                },
                "{task}: {n} evaluations"
            );
        }
        check_suite_available(&assets, TaskId::Aligning, ObsType::Image).unwrap();
        let e = check_suite_available(&assets, TaskId::Stacking, ObsType::Image)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("no robustness suite") && e.contains("image observations: aligning;"),
            "{e}"
        );
    }
}
