//! The `suite` field of a submission (docs/robustness.md): a
//! [`SuiteName`], and whether a task and observation type have a suite.

use super::{opt, RawSubmission};
use crate::error::AppError;
use d3il_protocol::{ObsType, SuiteName, TaskId};

pub(super) fn suite_field(raw: &RawSubmission) -> Result<Option<SuiteName>, AppError> {
    opt(raw, "suite")
        .map(|s| {
            SuiteName::parse(&s).map_err(|e| {
                AppError::invalid(
                    "suite",
                    format!("{e} (or leave `suite` out for a plain evaluation)"),
                )
            })
        })
        .transpose()
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quota::suite_evaluations;

    /// Every task has a state suite in the repository's assets, and every
    /// image variant an image suite, so a submission with
    /// `suite=robustness` is accepted for each, with its number of
    /// evaluations (level 0 and every level of the file); assets without a
    /// task's image suite refuse it, the message listing the tasks that
    /// have one.
    #[test]
    fn every_task_has_a_state_suite_and_every_image_variant_an_image_suite() {
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
            if task.has_image_variant() {
                check_suite_available(&assets, task, ObsType::Image).unwrap();
                // start_shift 3, latency 3 (Stacking 4), dynamics 4,
                // camera 3, lighting 3.
                let n = suite_evaluations(&assets, task, ObsType::Image);
                let latency = if task == TaskId::Stacking { 4 } else { 3 };
                assert_eq!(n, Some(14 + latency), "{task}");
            }
        }
        let partial = std::env::temp_dir().join(format!("d3il-suites-{}", std::process::id()));
        std::fs::create_dir_all(partial.join("robustness")).unwrap();
        for name in ["aligning-image-v1.json", "sorting-4-v1.json"] {
            std::fs::copy(
                assets.join("robustness").join(name),
                partial.join("robustness").join(name),
            )
            .unwrap();
        }
        let e = check_suite_available(&partial, TaskId::Stacking, ObsType::Image)
            .unwrap_err()
            .to_string();
        assert_eq!(
            suite_evaluations(&partial, TaskId::Stacking, ObsType::Image),
            None
        );
        std::fs::remove_dir_all(&partial).unwrap();
        assert!(
            e.contains("no robustness suite")
                && e.contains("state observations: sorting-4; image observations: aligning;"),
            "{e}"
        );
    }
}
