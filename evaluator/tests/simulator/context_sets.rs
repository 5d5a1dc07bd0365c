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
        let def = task_def(task).unwrap();
        let sets = def.context_sets().unwrap();
        assert_eq!(sets[0].name, def.context_set().unwrap().name, "{task}");
        for set in sets {
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
}

/// Aligning, Pushing and Stacking run the original D3IL test contexts (v2)
/// and keep our earlier samples (v1) loadable for stored results.
#[test]
fn the_original_test_contexts_are_in_use_and_v1_stays_loadable() {
    for (task, n) in [
        (TaskId::Aligning, 60),
        (TaskId::Pushing, 60),
        (TaskId::Stacking, 100),
    ] {
        let def = task_def(task).unwrap();
        let sets = def.context_sets().unwrap();
        let names: Vec<&str> = sets.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            [format!("{task}-v2.json"), format!("{task}-v1.json")]
        );
        assert_eq!(sets[0].len(), n);
        assert_eq!(sets[0].file.version, "v2");
        assert!(sets[0].file.seed.is_none());
        assert!(sets[0]
            .file
            .source
            .as_deref()
            .is_some_and(|s| s.contains("test_contexts.pkl")));
        assert_eq!(sets[1].len(), 60);
        assert!(sets[1].file.seed.is_some());
        // Every original context is a valid initial state of our environment.
        let loaded = d3il_evaluator::tasks::LoadedTask::load(task).unwrap();
        let mut env = loaded.env().unwrap();
        for (i, c) in sets[0].file.contexts.iter().enumerate() {
            env.reset(c)
                .unwrap_or_else(|e| panic!("{task} context {i}: {e}"));
        }
    }
    // The paper protocol's sizes on them: 60, the first 30, the first 60.
    let paper = |t: TaskId| {
        let d = task_def(t).unwrap();
        d.n_contexts_paper(d.context_set().unwrap().len())
    };
    assert_eq!(paper(TaskId::Aligning), 60);
    assert_eq!(paper(TaskId::Pushing), 30);
    assert_eq!(paper(TaskId::Stacking), 60);
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

/// Every sampled set is reproduced exactly by `d3il contexts generate` from
/// the seed it records. This is why the evaluator keeps rand 0.8 (ChaCha8
/// with rand 0.8's `gen_range`) while the policy and metrics crates use
/// rand 0.9: rand 0.9 changed its range sampling, so the recorded seeds
/// would no longer give the committed sets.
#[test]
fn every_sampled_set_is_reproduced_from_its_recorded_seed() {
    use d3il_evaluator::tasks::contexts::generate;
    let mut checked = 0;
    for task in ALL {
        let def = task_def(task).unwrap();
        for set in def.context_sets().unwrap() {
            let Some(seed) = set.file.seed else {
                assert!(
                    set.file.source.is_some(),
                    "{}: neither seed nor source",
                    set.name
                );
                continue;
            };
            let again = generate(def.as_ref(), seed, set.file.contexts.len());
            assert_eq!(again.contexts, set.file.contexts, "{}", set.name);
            checked += 1;
        }
    }
    assert!(checked >= 8, "only {checked} sampled sets were checked");
}
