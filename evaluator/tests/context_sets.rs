//! The committed initial-state sets (assets/contexts): every task's set loads
//! and matches the sha256 recorded in the code, and the same file with one
//! byte changed is refused with an error naming the file and the fix.

use d3il_evaluator::tasks::contexts::{sha256_hex, ContextSet};
use d3il_evaluator::tasks::task_def;
use d3il_protocol::TaskId;

const ALL: [TaskId; 8] = [
    TaskId::Avoiding,
    TaskId::Aligning,
    TaskId::Pushing,
    TaskId::Sorting2,
    TaskId::Sorting4,
    TaskId::Sorting6,
    TaskId::Stacking,
    TaskId::Inserting,
];

#[test]
fn every_committed_set_verifies_and_one_changed_byte_is_refused() {
    for task in ALL {
        let set = task_def(task).unwrap().context_set().unwrap();
        let path = format!(
            "{}/../assets/contexts/{}",
            env!("CARGO_MANIFEST_DIR"),
            set.name
        );
        let bytes = std::fs::read(&path).unwrap();
        // The file on disk is the one compiled in, with the recorded hash.
        assert_eq!(sha256_hex(&bytes), set.sha256, "{path}");
        assert!(ContextSet::verify(&set.name, &bytes, &set.sha256).is_ok());
        // Change one digit of one number (still valid JSON, same length).
        let mut bad = bytes.clone();
        let i = bad
            .iter()
            .rposition(|b| b.is_ascii_digit())
            .expect("the file has numbers");
        bad[i] = if bad[i] == b'9' { b'8' } else { bad[i] + 1 };
        assert!(serde_json::from_slice::<serde_json::Value>(&bad).is_ok());
        let err = ContextSet::verify(&set.name, &bad, &set.sha256)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&set.name) && err.contains("sha256") && err.contains("modified"),
            "{task}: {err}"
        );
    }
}

/// The protocol the pages announce (`TaskId::paper_protocol`, in the crate the
/// server uses) is the one the task definitions actually run.
#[test]
fn announced_protocol_matches_the_task_definitions() {
    for task in TaskId::ALL {
        let def = task_def(task).unwrap();
        let set = def.context_set().unwrap();
        let p = task.paper_protocol();
        assert_eq!(p.contexts, def.n_contexts_paper(set.len()), "{task}");
        assert_eq!(p.rollouts, def.rollouts_per_context(), "{task}");
        assert_eq!(p.max_steps, def.max_steps(), "{task}");
        assert_eq!(
            p.max_steps_image,
            task.has_image_variant().then(|| def.max_steps_image()),
            "{task}"
        );
    }
}
