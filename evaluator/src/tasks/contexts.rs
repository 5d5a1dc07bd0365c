//! Fixed, versioned initial-state sets (`assets/contexts/<task>-v<N>.json`).
//! A set is either sampled once from a recorded seed (`d3il contexts
//! generate`; all v1 sets) or imported from the original D3IL test contexts
//! (`d3il contexts import`; Aligning, Pushing and Stacking v2, from
//! `shared/reference-contexts`), then committed; the evaluator refuses a file
//! whose sha256 differs from the hash recorded in the code, so a leaderboard
//! number always refers to exactly one set of initial states, which every
//! result names (file and sha256) in its protocol manifest.

use super::TaskError;
use d3il_protocol::TaskId;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use sha2::{Digest, Sha256};

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ContextFile {
    pub task: TaskId,
    pub version: String,
    /// Seed the set was sampled from (ChaCha8), for the record; absent for an
    /// imported set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    pub description: String,
    /// Where an imported set comes from; absent for a sampled one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
    pub contexts: Vec<Value>,
}

/// A file of the original test contexts as `shared/reference-contexts` holds
/// them: `{"source": ..., "contexts": [...]}`.
#[derive(Debug, Clone, Deserialize)]
pub struct ReferenceContexts {
    pub source: String,
    pub contexts: Vec<Value>,
}

/// A verified initial-state set.
#[derive(Debug, Clone)]
pub struct ContextSet {
    pub name: String,
    pub sha256: String,
    pub file: ContextFile,
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

impl ContextSet {
    /// Parses `bytes` after checking their sha256 against `expected_sha256`.
    pub fn verify(
        name: &str,
        bytes: &[u8],
        expected_sha256: &str,
    ) -> Result<ContextSet, TaskError> {
        let got = sha256_hex(bytes);
        if got != expected_sha256 {
            return Err(TaskError::ContextSet {
                name: name.into(),
                message: format!(
                    "sha256 is {got} but this evaluator expects {expected_sha256}; the file was modified. \
                     Restore it from the repository (git checkout assets/contexts/{name}) — initial-state sets are versioned and never edited in place"
                ),
            });
        }
        let file: ContextFile =
            serde_json::from_slice(bytes).map_err(|e| TaskError::ContextSet {
                name: name.into(),
                message: format!("not a valid context file: {e}"),
            })?;
        Ok(ContextSet {
            name: name.into(),
            sha256: got,
            file,
        })
    }

    pub fn len(&self) -> usize {
        self.file.contexts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.file.contexts.is_empty()
    }

    pub fn get(&self, i: usize) -> Option<&Value> {
        self.file.contexts.get(i)
    }
}

/// Accepts a context written with another naming of its objects as it is:
/// every key `<alias>_<rest>` becomes `<name>_<rest>` for each
/// `(alias, name)` (e.g. Inserting's `box1_xy_deg` → `red_xy_deg`). Giving
/// the same field under both names is an error naming both.
pub fn rename_objects(
    task: TaskId,
    context: &Value,
    aliases: &[(&str, &str)],
) -> Result<Value, TaskError> {
    let Some(obj) = context.as_object() else {
        return Ok(context.clone());
    };
    let mut out = serde_json::Map::new();
    for (key, v) in obj {
        let renamed = aliases.iter().find_map(|(alias, name)| {
            key.strip_prefix(alias)
                .filter(|rest| rest.starts_with('_'))
                .map(|rest| format!("{name}{rest}"))
        });
        let new_key = renamed.unwrap_or_else(|| key.clone());
        if out.contains_key(&new_key) || (new_key != *key && obj.contains_key(&new_key)) {
            return Err(TaskError::Context {
                task,
                message: format!(
                    "field `{key}` and field `{new_key}` name the same thing; give only one of them"
                ),
            });
        }
        out.insert(new_key, v.clone());
    }
    Ok(Value::Object(out))
}

/// Samples a new context file for a task (used once per version, then committed).
pub fn generate(task: &dyn super::TaskDef, seed: u64, n: usize) -> ContextFile {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let contexts = (0..n).map(|_| task.sample_context(&mut rng)).collect();
    ContextFile {
        task: task.id(),
        version: task.version().into(),
        seed: Some(seed),
        description: format!(
            "{} fixed initial states for {}, sampled from the task's context distribution with ChaCha8 seed {seed}",
            n,
            task.id()
        ),
        source: None,
        contexts,
    }
}

/// A set made of the original D3IL test contexts, in their order, unchanged.
pub fn import(task: TaskId, version: &str, reference: ReferenceContexts) -> ContextFile {
    ContextFile {
        task,
        version: version.into(),
        seed: None,
        description: format!(
            "the original D3IL test contexts of {task} ({} initial states, in the reference's order; the paper's protocol uses the first {})",
            reference.contexts.len(),
            task.paper_protocol().contexts
        ),
        source: Some(reference.source),
        contexts: reference.contexts,
    }
}

/// Pretty JSON with a trailing newline: the committed byte format.
pub fn to_bytes(file: &ContextFile) -> Vec<u8> {
    let mut s = serde_json::to_string_pretty(file).expect("context files serialise");
    s.push('\n');
    s.into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_object_names_are_renamed_and_clashes_refused() {
        let aliases = [("box1", "red"), ("box2", "green"), ("box3", "blue")];
        let c = serde_json::json!({"box1_xy_deg": [0.1, 0.2, 3.0], "box3_quat": [1, 0, 0, 0], "format": "x"});
        let r = rename_objects(TaskId::Inserting, &c, &aliases).unwrap();
        assert_eq!(
            r,
            serde_json::json!({"red_xy_deg": [0.1, 0.2, 3.0], "blue_quat": [1, 0, 0, 0], "format": "x"})
        );
        let clash =
            serde_json::json!({"box1_xy_deg": [0.1, 0.2, 3.0], "red_xy_deg": [0.1, 0.2, 3.0]});
        let e = rename_objects(TaskId::Inserting, &clash, &aliases)
            .unwrap_err()
            .to_string();
        assert!(e.contains("box1_xy_deg") && e.contains("red_xy_deg"), "{e}");
        // `box10_...` is not `box1`'s.
        let other = serde_json::json!({"box10_xy_deg": 1});
        assert_eq!(
            rename_objects(TaskId::Inserting, &other, &aliases).unwrap(),
            other
        );
    }

    #[test]
    fn a_changed_byte_is_refused_with_a_clear_error() {
        let file = ContextFile {
            task: TaskId::Aligning,
            version: "v1".into(),
            seed: Some(1),
            description: "x".into(),
            source: None,
            contexts: vec![serde_json::json!({"a": 1})],
        };
        let bytes = to_bytes(&file);
        let sha = sha256_hex(&bytes);
        assert!(ContextSet::verify("t.json", &bytes, &sha).is_ok());
        let mut bad = bytes.clone();
        let i = bad.iter().position(|&b| b == b'1').unwrap();
        bad[i] = b'2';
        let err = ContextSet::verify("t.json", &bad, &sha)
            .unwrap_err()
            .to_string();
        assert!(err.contains("sha256") && err.contains("modified"), "{err}");
    }
}
