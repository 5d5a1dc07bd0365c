//! Fixed, versioned initial-state sets (`assets/contexts/<task>-v<N>.json`).
//! Each set is generated once from a recorded seed (`d3il contexts generate`)
//! and committed; the evaluator refuses a file whose sha256 differs from the
//! hash recorded in the code, so a leaderboard number always refers to exactly
//! one set of initial states.

use super::TaskError;
use d3il_protocol::TaskId;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use sha2::{Digest, Sha256};

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ContextFile {
    pub task: TaskId,
    pub version: String,
    /// Seed the set was sampled from (ChaCha8), for the record.
    pub seed: u64,
    pub description: String,
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

/// Samples a new context file for a task (used once per version, then committed).
pub fn generate(task: &dyn super::TaskDef, seed: u64, n: usize) -> ContextFile {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let contexts = (0..n).map(|_| task.sample_context(&mut rng)).collect();
    ContextFile {
        task: task.id(),
        version: task.version().into(),
        seed,
        description: format!(
            "{} fixed initial states for {}, sampled from the task's context distribution with ChaCha8 seed {seed}",
            n,
            task.id()
        ),
        contexts,
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
    fn a_changed_byte_is_refused_with_a_clear_error() {
        let file = ContextFile {
            task: TaskId::Aligning,
            version: "v1".into(),
            seed: 1,
            description: "x".into(),
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
