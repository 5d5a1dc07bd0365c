//! The drift canary (`d3il verify`): a fixed set of small evaluations per
//! task whose per-rollout outcomes — success, behaviour, steps, how it ended,
//! the final object poses and the final physics-state digest, to the bit —
//! are committed (`assets/canary/expected.json`). A build that reproduces
//! them simulates as the build that recorded them; one that does not has
//! drifted, and says where. The hash of the outcomes is the build's
//! **physics fingerprint**, recorded in every result's manifest: results
//! whose fingerprints differ are never averaged or ranked together.
//!
//! Each entry runs the quick protocol's initial states, every rollout capped
//! at a number of steps (a drift shows within the first steps of contact;
//! the cap keeps `d3il verify` under a minute on one machine).

use crate::eval::{evaluate, sha256_hex, EvalOptions, EvalRun, PolicyInfo};
use crate::scripted::ScriptedPolicy;
use crate::tasks::LoadedTask;
use d3il_policy::{OnnxPolicy, Policy};
use d3il_protocol::{trace_of, ObsType, PolicyManifest, ProtocolKind, TaskId};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One canary evaluation.
#[derive(Debug, Clone, Copy)]
pub struct Entry {
    pub task: TaskId,
    pub obs: ObsType,
    /// `scripted:<name>` or the name of an ONNX fixture in `assets/fixtures`.
    pub policy: &'static str,
    /// Steps after which every rollout is stopped.
    pub step_cap: usize,
    /// Rollouts simulated at once (`None`: the engine's default, more than
    /// the quick protocol has); fewer than the rollouts makes slots be reused.
    pub max_live: Option<usize>,
}

const fn entry(task: TaskId, obs: ObsType, policy: &'static str, step_cap: usize) -> Entry {
    Entry {
        task,
        obs,
        policy,
        step_cap,
        max_live: None,
    }
}

/// The canary: every task's scripted expert, the ONNX state fixtures of
/// Avoiding and Aligning (one with a `noise` input) and two image fixtures,
/// one with a history of two frames run in one slot, so that each initial
/// state's first window is built in a slot another rollout used before.
pub const ENTRIES: [Entry; 13] = [
    entry(
        TaskId::Avoiding,
        ObsType::State,
        "scripted:avoiding:all-paths",
        120,
    ),
    entry(TaskId::Avoiding, ObsType::State, "avoiding_k5_h3", 120),
    entry(
        TaskId::Aligning,
        ObsType::State,
        "scripted:aligning:both",
        120,
    ),
    entry(TaskId::Aligning, ObsType::State, "aligning_mlp_noise", 120),
    entry(TaskId::Aligning, ObsType::Image, "aligning_image", 25),
    Entry {
        max_live: Some(1),
        ..entry(TaskId::Aligning, ObsType::Image, "aligning_image_k2_h4", 25)
    },
    entry(
        TaskId::Pushing,
        ObsType::State,
        "scripted:pushing:all-modes",
        120,
    ),
    entry(
        TaskId::Sorting2,
        ObsType::State,
        "scripted:sorting-2:all-orders",
        120,
    ),
    entry(
        TaskId::Sorting4,
        ObsType::State,
        "scripted:sorting-4:all-orders",
        120,
    ),
    entry(
        TaskId::Sorting6,
        ObsType::State,
        "scripted:sorting-6:all-orders",
        120,
    ),
    entry(
        TaskId::Stacking,
        ObsType::State,
        "scripted:stacking:all-orders",
        120,
    ),
    entry(
        TaskId::Inserting,
        ObsType::State,
        "scripted:inserting:box=r",
        120,
    ),
    entry(
        TaskId::Stacking,
        ObsType::State,
        "scripted:stacking:order=rgb",
        300,
    ),
];

impl Entry {
    /// `task/obs/policy`, the entry's name in tables and the expected file.
    pub fn name(&self) -> String {
        format!("{}/{}/{}", self.task, self.obs, self.policy)
    }
}

/// What one rollout of an entry did, to the bit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutOutcome {
    pub number: usize,
    pub success: bool,
    pub behaviour: serde_json::Value,
    pub steps: usize,
    pub ending: Option<d3il_protocol::Ending>,
    /// Final object positions (f64, written so they read back bit for bit).
    pub final_objects: Vec<(String, [f64; 3])>,
    /// The state digest after the last step (`qpos`, `qvel`).
    pub final_digest: Option<u32>,
}

/// The outcomes of one entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EntryOutcome {
    pub entry: String,
    pub rollouts: Vec<RolloutOutcome>,
}

/// The canary's outcomes, as a build computes them or as committed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Outcomes {
    pub entries: Vec<EntryOutcome>,
}

impl Outcomes {
    /// The physics fingerprint: sha256 of the outcomes' JSON, 16 hex digits.
    pub fn fingerprint(&self) -> String {
        let json = serde_json::to_vec(self).expect("plain data");
        sha256_hex(&json)[..16].to_string()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum CanaryError {
    #[error("canary entry {entry}: {message}")]
    Entry { entry: String, message: String },
}

fn load_policy(
    e: &Entry,
    task: &LoadedTask,
    assets: &Path,
) -> Result<(Box<dyn Policy>, PolicyInfo), String> {
    if let Some(name) = e.policy.strip_prefix("scripted:") {
        let p = ScriptedPolicy::from_name(name, task.spec()).map_err(|e| e.to_string())?;
        return Ok((
            Box::new(p),
            PolicyInfo {
                sha256: sha256_hex(name.as_bytes()),
                obs_type: ObsType::State,
            },
        ));
    }
    let dir = assets.join("fixtures");
    let read = |ext: &str| {
        let f = dir.join(format!("{}.{ext}", e.policy));
        std::fs::read(&f).map_err(|err| format!("cannot read {}: {err}", f.display()))
    };
    let bytes = read("onnx")?;
    let manifest: PolicyManifest =
        serde_json::from_slice(&read("json")?).map_err(|e| e.to_string())?;
    let p = OnnxPolicy::load(&bytes, &manifest, &task.spec(), 0).map_err(|e| e.to_string())?;
    Ok((
        Box::new(p),
        PolicyInfo {
            sha256: sha256_hex(&bytes),
            obs_type: e.obs,
        },
    ))
}

/// Runs one entry.
pub fn run_entry(e: &Entry, assets: &Path) -> Result<EntryOutcome, CanaryError> {
    let err = |message: String| CanaryError::Entry {
        entry: e.name(),
        message,
    };
    let task = LoadedTask::load_obs(e.task, e.obs).map_err(|x| err(x.to_string()))?;
    let (mut policy, info) = load_policy(e, &task, assets).map_err(err)?;
    let opts = EvalOptions {
        protocol: ProtocolKind::Quick,
        step_cap: Some(e.step_cap),
        bootstrap_resamples: 10,
        max_live: e.max_live.unwrap_or(EvalOptions::default().max_live),
        ..EvalOptions::default()
    };
    let (result, _) = evaluate(&task, policy.as_mut(), &info, &opts, EvalRun::all())
        .map_err(|x| err(x.to_string()))?;
    let per = result.manifest.rollouts_per_context;
    let rollouts = result
        .rollouts
        .iter()
        .map(|r| {
            let trace = trace_of(&result.manifest, &result.rollouts, r);
            RolloutOutcome {
                number: r.number(per),
                success: r.success,
                behaviour: r.behaviour.clone(),
                steps: r.steps,
                ending: r.ending,
                final_objects: trace.map(|t| t.final_objects.clone()).unwrap_or_default(),
                final_digest: trace
                    .and_then(|t| t.unpack().ok())
                    .and_then(|t| t.digests.last().copied()),
            }
        })
        .collect();
    Ok(EntryOutcome {
        entry: e.name(),
        rollouts,
    })
}

/// Runs every entry, calling `on_entry` after each.
pub fn run(
    assets: &Path,
    on_entry: &mut dyn FnMut(&EntryOutcome),
) -> Result<Outcomes, CanaryError> {
    let mut entries = Vec::new();
    for e in &ENTRIES {
        let o = run_entry(e, assets)?;
        on_entry(&o);
        entries.push(o);
    }
    Ok(Outcomes { entries })
}

/// How one entry compares with the committed expectation.
#[derive(Debug, Clone, Serialize)]
pub struct EntryCheck {
    pub entry: String,
    pub rollouts: usize,
    pub matching: usize,
    /// The first difference, in words (None: every rollout matches).
    pub first_difference: Option<String>,
}

/// Compares computed outcomes with the expected ones, entry by entry.
pub fn compare(expected: &Outcomes, got: &Outcomes) -> Vec<EntryCheck> {
    got.entries
        .iter()
        .map(|g| {
            let Some(x) = expected.entries.iter().find(|x| x.entry == g.entry) else {
                return EntryCheck {
                    entry: g.entry.clone(),
                    rollouts: g.rollouts.len(),
                    matching: 0,
                    first_difference: Some("no expectation is committed for this entry".into()),
                };
            };
            let mut first = None;
            let mut matching = 0;
            for (i, r) in g.rollouts.iter().enumerate() {
                match x.rollouts.get(i) {
                    Some(e) if e == r && bits_equal(e, r) => matching += 1,
                    Some(e) => {
                        first.get_or_insert_with(|| describe_difference(e, r));
                    }
                    None => {
                        first
                            .get_or_insert_with(|| format!("rollout {} is not expected", r.number));
                    }
                }
            }
            if x.rollouts.len() != g.rollouts.len() {
                first.get_or_insert_with(|| {
                    format!(
                        "{} rollouts expected, {} run",
                        x.rollouts.len(),
                        g.rollouts.len()
                    )
                });
            }
            EntryCheck {
                entry: g.entry.clone(),
                rollouts: g.rollouts.len(),
                matching,
                first_difference: first,
            }
        })
        .collect()
}

/// Equality of the final poses to the bit (== on f64 would let -0.0 = 0.0 pass).
fn bits_equal(a: &RolloutOutcome, b: &RolloutOutcome) -> bool {
    let bits = |o: &RolloutOutcome| -> Vec<(String, [u64; 3])> {
        o.final_objects
            .iter()
            .map(|(n, p)| (n.clone(), p.map(f64::to_bits)))
            .collect()
    };
    bits(a) == bits(b)
}

fn describe_difference(e: &RolloutOutcome, g: &RolloutOutcome) -> String {
    let n = g.number;
    if e.steps != g.steps {
        return format!("rollout {n}: {} steps expected, {} now", e.steps, g.steps);
    }
    if e.success != g.success || e.behaviour != g.behaviour {
        return format!(
            "rollout {n}: success {} / behaviour {} expected, {} / {} now",
            e.success, e.behaviour, g.success, g.behaviour
        );
    }
    if e.final_digest != g.final_digest {
        return format!(
            "rollout {n}: the final physics state differs (digest {:?} expected, {:?} now)",
            e.final_digest, g.final_digest
        );
    }
    format!(
        "rollout {n}: the final object poses differ: {:?} expected, {:?} now",
        e.final_objects, g.final_objects
    )
}

/// The committed expectation (`assets/canary/expected.json`).
pub fn expected(assets: &Path) -> Result<Outcomes, String> {
    let f = assets.join("canary/expected.json");
    let text =
        std::fs::read_to_string(&f).map_err(|e| format!("cannot read {}: {e}", f.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{} does not parse: {e}", f.display()))
}
