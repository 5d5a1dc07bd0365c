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

/// Whether `task` with `obs` observations has a robustness suite: state
/// policies of the tasks with a suite file in `assets/robustness/` (the
/// worker's `d3il_evaluator::robustness::suite_for` checks the same, with
/// the files' sha256, before it evaluates).
pub fn check_suite_available(
    assets_dir: &std::path::Path,
    task: TaskId,
    obs: ObsType,
) -> Result<(), AppError> {
    let dir = assets_dir.join("robustness");
    let with_suite: Vec<TaskId> = TaskId::ALL
        .iter()
        .copied()
        .filter(|t| {
            std::fs::read_dir(&dir).is_ok_and(|entries| {
                entries.flatten().any(|e| {
                    let name = e.file_name().to_string_lossy().into_owned();
                    name.starts_with(&format!("{}-v", t.slug())) && name.ends_with(".json")
                })
            })
        })
        .collect();
    let names = with_suite
        .iter()
        .map(|t| t.slug())
        .collect::<Vec<_>>()
        .join(", ");
    if !with_suite.contains(&task) {
        return Err(AppError::invalid(
            "suite",
            format!("task `{task}` has no robustness suite yet; suites exist for {names} (state observations); leave `suite` out for a plain evaluation"),
        ));
    }
    if obs != ObsType::State {
        return Err(AppError::invalid(
            "suite",
            format!("the robustness suite of `{task}` has no axes for {obs} observations yet (state policies only); leave `suite` out for a plain evaluation"),
        ));
    }
    Ok(())
}
