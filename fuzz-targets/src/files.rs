//! Files a user hands in: policy manifests, initial-state sets, and the part
//! files `d3il merge` joins.

use crate::assert_described;
use d3il_evaluator::tasks::{contexts, Env, LoadedTask};
use d3il_protocol::shard::EvalPart;
use d3il_protocol::{PolicyManifest, TaskId};
use std::cell::RefCell;
use std::collections::HashMap;

/// A policy manifest as intake (`manifest` field, `manifest_file`), `d3il
/// eval --manifest` and the worker read it: JSON into [`PolicyManifest`],
/// then [`PolicyManifest::validate`] and, per task, `validate_for`.
/// Properties: a manifest that parses re-serialises and parses back to the
/// same value; every refusal has a message.
pub fn manifest(data: &[u8]) {
    // Intake refuses a manifest that is not UTF-8 before it parses it.
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let m: PolicyManifest = match serde_json::from_str(text) {
        Ok(m) => m,
        Err(e) => return assert_described("manifest parse", &e),
    };
    let again = serde_json::to_string(&m).expect("a parsed manifest serialises");
    let back: PolicyManifest = serde_json::from_str(&again).unwrap_or_else(|e| {
        panic!("the manifest re-serialised as {again} does not parse again: {e}")
    });
    assert_eq!(back, m, "the manifest changed through {again}");
    if let Err(e) = m.validate() {
        return assert_described("manifest validate", &e);
    }
    for task in TaskId::ALL {
        let Ok(def) = d3il_evaluator::tasks::task_def(task) else {
            continue;
        };
        for obs in [d3il_protocol::ObsType::State, d3il_protocol::ObsType::Image] {
            if let Err(e) = m.validate_for(&def.spec_for(obs)) {
                assert_described("manifest validate_for", &e);
            }
        }
    }
}

thread_local! {
    /// One environment per task, loaded on first use (loading compiles the
    /// scene; a reset is what a context drives).
    static ENVS: RefCell<HashMap<TaskId, Env>> = RefCell::new(HashMap::new());
}

/// Resets `task`'s environment to each of the first few `contexts`, as
/// `d3il contexts import` checks every imported context and as an
/// evaluation starts every rollout: Ok, or an error with a message.
fn reset_each(task: TaskId, contexts: &[serde_json::Value]) {
    ENVS.with(|envs| {
        let mut envs = envs.borrow_mut();
        if let std::collections::hash_map::Entry::Vacant(slot) = envs.entry(task) {
            let loaded = LoadedTask::load(task).expect("the committed task loads");
            slot.insert(loaded.env().expect("the committed task makes an env"));
        }
        let env = envs.get_mut(&task).expect("inserted above");
        for c in contexts.iter().take(4) {
            if let Err(e) = env.reset(c) {
                assert_described("context reset", &e);
            }
        }
    });
}

/// An initial-state set: the first byte picks the task a reference file
/// (`{"source", "contexts"}`, what `d3il contexts import` reads) is
/// imported for; the rest is the file. A versioned set
/// (`assets/contexts/<task>-v<N>.json`) is read with
/// [`contexts::ContextSet::verify`] (its own hash, so the parse is reached)
/// and must write back ([`contexts::to_bytes`]) to a file that reads the
/// same. Every context read is then reset to in its task's environment.
pub fn contexts(data: &[u8]) {
    let Some((&pick, file)) = data.split_first() else {
        return;
    };
    match contexts::ContextSet::verify("fuzz.json", file, &contexts::sha256_hex(file)) {
        Ok(set) => {
            let bytes = contexts::to_bytes(&set.file);
            let again =
                contexts::ContextSet::verify("again.json", &bytes, &contexts::sha256_hex(&bytes))
                    .unwrap_or_else(|e| panic!("a context set written back does not read: {e}"));
            let value = |f: &contexts::ContextFile| serde_json::to_value(f).expect("serialises");
            assert_eq!(
                value(&again.file),
                value(&set.file),
                "the set changed when written back"
            );
            reset_each(set.file.task, &set.file.contexts);
        }
        Err(e) => {
            assert_described("context set", &e);
            match serde_json::from_slice::<contexts::ReferenceContexts>(file) {
                Ok(reference) => {
                    let task = TaskId::ALL[usize::from(pick) % TaskId::ALL.len()];
                    reset_each(task, &reference.contexts);
                    let imported = contexts::import(task, "v9", reference);
                    let bytes = contexts::to_bytes(&imported);
                    contexts::ContextSet::verify(
                        "imported.json",
                        &bytes,
                        &contexts::sha256_hex(&bytes),
                    )
                    .unwrap_or_else(|e| panic!("an imported set does not read back: {e}"));
                }
                Err(e) => assert_described("reference contexts", &e),
            }
        }
    }
}

/// The part files of `d3il merge`, separated by NUL bytes (which JSON
/// text cannot hold): each parsed as the command does, then
/// [`d3il_metrics::shard::merge`]. Properties: the parts merge to the same
/// result (or are refused) in any order, as `d3il merge` promises; errors
/// have messages.
pub fn merge(data: &[u8]) {
    let mut parts = Vec::new();
    for (i, bytes) in data.split(|&b| b == 0).take(8).enumerate() {
        match serde_json::from_slice::<EvalPart>(bytes) {
            Ok(p) => parts.push((format!("part{i}.json"), p)),
            Err(e) => return assert_described("part file", &e),
        }
    }
    let mut reversed = parts.clone();
    reversed.reverse();
    let forward = d3il_metrics::shard::merge(parts);
    let backward = d3il_metrics::shard::merge(reversed);
    match (forward, backward) {
        (Ok(a), Ok(b)) => {
            let a = serde_json::to_string(&a).expect("a merged result serialises");
            let b = serde_json::to_string(&b).expect("a merged result serialises");
            assert_eq!(a, b, "the parts merge differently in reverse order");
        }
        (Err(a), Err(b)) => {
            assert_described("merge", &a);
            assert_described("merge (reversed)", &b);
        }
        (a, b) => panic!(
            "the parts merge in one order and not in the other: forward {:?}, reversed {:?}",
            a.map(|_| "merged"),
            b.map(|_| "merged")
        ),
    }
}
