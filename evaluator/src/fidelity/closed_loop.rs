//! (b) Closed loop: the policies of `reference-closed-loop/` (ONNX +
//! manifest, and `<name>.original.json`: what each did in the original,
//! one rollout per initial state) evaluated here with the engine, compared
//! in distribution (success rates with 95 % intervals both ways) and state
//! by state; then the original's actions replayed open-loop here against the
//! original's TCP path.

use super::{actions, dist, read_json, rows, FidelityError};
use crate::eval::{evaluate, sha256_hex, EvalOptions, EvalRun};
use crate::job::load_policy;
use crate::open_loop::{replay_actions, OpenLoopOptions};
use crate::tasks::LoadedTask;
use d3il_protocol::fidelity::{
    ClosedLoopSection, ContextAgreement, FidelityMode, OpenLoopEpisode, PolicyFidelity, Rate,
};
use d3il_protocol::{EvalResult, Job, Limits, PolicyManifest, PolicySource, ProtocolKind, TaskId};
use rayon::prelude::*;
use serde_json::Value;
use std::path::Path;

/// The original's TCP is followed while ours is this close (m).
pub const TCP_TOLERANCE_M: f64 = 1e-9;

/// One rollout recorded in the original.
#[derive(Debug, Clone)]
pub struct OriginalRollout {
    pub context: usize,
    pub success: bool,
    pub behaviour: Value,
    pub steps: usize,
    pub actions: Vec<Vec<f32>>,
    pub tcp: Vec<Vec<f64>>,
}

/// `<name>.original.json`.
#[derive(Debug, Clone)]
pub struct Original {
    pub task: TaskId,
    pub description: String,
    pub rollouts: Vec<OriginalRollout>,
}

pub fn read_original(path: &Path) -> Result<Original, FidelityError> {
    let v = read_json(path)?;
    let task: TaskId = v["task"]
        .as_str()
        .unwrap_or_default()
        .parse()
        .map_err(|_| FidelityError::data(path, "`task` is not a task name"))?;
    let text = |k: &str| {
        v[k].as_str()
            .map(str::to_string)
            .unwrap_or_else(|| "none".into())
    };
    let description = format!(
        "in the original: {}; inference {}; noise {}",
        text("simulator"),
        text("inference"),
        text("noise")
    );
    let mut rollouts = vec![];
    for r in v["rollouts"].as_array().into_iter().flatten() {
        let num = |k: &str| {
            r[k].as_u64()
                .map(|x| x as usize)
                .ok_or_else(|| FidelityError::data(path, format!("rollout `{k}` must be a count")))
        };
        rollouts.push(OriginalRollout {
            context: num("context_index")?,
            success: r["success"]
                .as_bool()
                .ok_or_else(|| FidelityError::data(path, "rollout `success` must be a boolean"))?,
            behaviour: r["behaviour"].clone(),
            steps: num("steps")?,
            actions: actions(&r["actions"], path, "actions")?,
            tcp: rows(&r["tcp"], path, "tcp")?,
        });
    }
    if rollouts.is_empty() {
        return Err(FidelityError::data(path, "no rollouts"));
    }
    Ok(Original {
        task,
        description,
        rollouts,
    })
}

/// Evaluates `<name>.onnx` (manifest `<name>.json`) here under `protocol`
/// with seed 0, as `d3il eval` does in process; `rollouts_per_state` as
/// [`EvalOptions::rollouts_per_state`].
pub fn evaluate_here(
    dir: &Path,
    name: &str,
    task: TaskId,
    protocol: ProtocolKind,
    rollouts_per_state: Option<usize>,
) -> Result<EvalResult, FidelityError> {
    let onnx = dir.join(format!("{name}.onnx"));
    let bytes = std::fs::read(&onnx).map_err(|e| FidelityError::data(&onnx, e))?;
    let mpath = dir.join(format!("{name}.json"));
    let manifest: PolicyManifest =
        serde_json::from_value(read_json(&mpath)?).map_err(|e| FidelityError::data(&mpath, e))?;
    let job = Job {
        kind: d3il_protocol::JobKind::Plain,
        job_id: format!("fidelity-{name}"),
        task,
        protocol,
        policy: PolicySource::Onnx {
            path: onnx.to_string_lossy().into_owned(),
            sha256: sha256_hex(&bytes),
        },
        manifest,
        seed: 0,
        limits: Limits::default(),
        assets_dir: String::new(),
        dry_run_steps: None,
        build: None,
    };
    let loaded = LoadedTask::load_obs(task, job.manifest.obs_type)?;
    let (mut policy, info) = load_policy(&job, &loaded)?;
    let opts = EvalOptions {
        protocol,
        rollouts_per_state,
        ..EvalOptions::default()
    };
    let (result, _) = evaluate(&loaded, policy.as_mut(), &info, &opts, EvalRun::all())?;
    Ok(result)
}

/// The original's actions replayed from the same initial state here: how
/// long our TCP stays within [`TCP_TOLERANCE_M`] of the original's.
pub fn replay_original(
    loaded: &LoadedTask,
    o: &OriginalRollout,
) -> Result<OpenLoopEpisode, FidelityError> {
    let set = loaded.def.context_set()?;
    let context = set
        .get(o.context)
        .cloned()
        .ok_or_else(|| FidelityError::Data {
            path: "reference-closed-loop".into(),
            message: format!("initial state {} is not in our set", o.context),
        })?;
    let run = replay_actions(loaded, &context, &o.actions, OpenLoopOptions::default()).map_err(
        |source| FidelityError::Replay {
            what: format!("the original's actions of initial state {}", o.context),
            source,
        },
    )?;
    let n = run.tcp.len().min(o.tcp.len());
    let devs: Vec<f64> = (0..n).map(|t| dist(&run.tcp[t], &o.tcp[t])).collect();
    let first_off = devs.iter().position(|&d| d > TCP_TOLERANCE_M);
    let steps_within = match first_off {
        Some(0) => 0,
        Some(t) => t - 1,
        None => n.saturating_sub(1),
    };
    Ok(OpenLoopEpisode {
        context: o.context,
        steps_original: o.steps,
        steps_within,
        whole_episode: first_off.is_none() && n == o.tcp.len() && run.steps == o.steps,
        max_within_m: devs[..first_off.unwrap_or(n)]
            .iter()
            .fold(0.0, |a: f64, &b| a.max(b)),
        closed_loop_same_success: false,
        replay_same_success: run.success == o.success && run.steps == o.steps,
    })
}

/// One policy: here against there.
pub fn compare(
    dir: &Path,
    name: &str,
    mode: FidelityMode,
) -> Result<PolicyFidelity, FidelityError> {
    compare_sampled(dir, name, mode, None)
}

/// [`compare`] with `rollouts_per_state` rollouts of each initial state here
/// instead of the protocol's (a cheaper sample for tests; `None`: all).
pub fn compare_sampled(
    dir: &Path,
    name: &str,
    mode: FidelityMode,
    rollouts_per_state: Option<usize>,
) -> Result<PolicyFidelity, FidelityError> {
    let original = read_original(&dir.join(format!("{name}.original.json")))?;
    let protocol = match mode {
        FidelityMode::Full => ProtocolKind::Paper,
        FidelityMode::Quick => ProtocolKind::Quick,
    };
    let here = evaluate_here(dir, name, original.task, protocol, rollouts_per_state)?;
    let n_ctx = here.manifest.n_contexts;
    let per = here.manifest.rollouts_per_context;
    let theirs: Vec<&OriginalRollout> = original
        .rollouts
        .iter()
        .filter(|r| r.context < n_ctx)
        .collect();
    let mut per_context = vec![];
    let (mut same_success, mut same_behaviour, mut compared) = (0usize, 0usize, 0usize);
    for o in &theirs {
        let ours: Vec<_> = here
            .rollouts
            .iter()
            .filter(|r| r.context_index == o.context)
            .collect();
        let succ = ours.iter().filter(|r| r.success).count();
        let beh = ours.iter().filter(|r| r.behaviour == o.behaviour).count();
        same_success += ours.iter().filter(|r| r.success == o.success).count();
        same_behaviour += beh;
        compared += ours.len();
        per_context.push(ContextAgreement {
            context: o.context,
            original_success: o.success,
            original_behaviour: o.behaviour.clone(),
            original_steps: o.steps,
            here_successes: succ,
            here_rollouts: ours.len(),
            here_same_behaviour: beh,
            here_mean_steps: ours.iter().map(|r| r.steps as f64).sum::<f64>()
                / ours.len().max(1) as f64,
        });
    }
    let k = theirs.iter().filter(|r| r.success).count();
    let (lo, hi) = d3il_metrics::wilson_interval(k, theirs.len(), 0.05);
    let original_rate = Rate {
        successes: k,
        rollouts: theirs.len(),
        value: k as f64 / theirs.len().max(1) as f64,
        ci_low: lo,
        ci_high: hi,
        interval: "Wilson score interval (one rollout per initial state)".into(),
    };
    let m = here.metrics.success_rate;
    let here_rate = Rate {
        successes: here.rollouts.iter().filter(|r| r.success).count(),
        rollouts: here.rollouts.len(),
        value: m.value,
        ci_low: m.ci_low,
        ci_high: m.ci_high,
        interval: "bootstrap over initial states (the evaluator's interval)".into(),
    };
    let loaded = LoadedTask::load(original.task)?;
    let mut open_loop = theirs
        .par_iter()
        .map(|o| replay_original(&loaded, o))
        .collect::<Result<Vec<_>, _>>()?;
    for e in &mut open_loop {
        e.closed_loop_same_success = here
            .rollouts
            .iter()
            .find(|r| r.context_index == e.context && r.rollout_index == 0)
            .zip(theirs.iter().find(|o| o.context == e.context))
            .is_some_and(|(r, o)| r.success == o.success);
    }
    Ok(PolicyFidelity {
        name: name.into(),
        task: original.task.to_string(),
        description: original.description,
        contexts: theirs.len(),
        rollouts_per_context_here: per,
        here_inside_original_interval: original_rate.contains(here_rate.value),
        original_inside_here_interval: here_rate.contains(original_rate.value),
        original: original_rate,
        here: here_rate,
        success_agreement: same_success as f64 / compared.max(1) as f64,
        behaviour_agreement: same_behaviour as f64 / compared.max(1) as f64,
        per_context,
        open_loop,
    })
}

/// Every policy with an `.original.json` in `dir`, by name.
pub fn section(
    dir: &Path,
    mode: FidelityMode,
    progress: &mut dyn FnMut(&str),
) -> Result<ClosedLoopSection, FidelityError> {
    let entries = std::fs::read_dir(dir).map_err(|e| FidelityError::data(dir, e))?;
    let mut names: Vec<String> = entries
        .flatten()
        .filter_map(|e| {
            e.file_name()
                .to_str()
                .and_then(|f| f.strip_suffix(".original.json"))
                .map(str::to_string)
        })
        .collect();
    names.sort();
    let mut policies = vec![];
    for name in names {
        progress(&format!(
            "evaluating {name} here and replaying the original's actions"
        ));
        policies.push(compare(dir, &name, mode)?);
    }
    Ok(ClosedLoopSection {
        protocol: match mode {
            FidelityMode::Full => "paper".into(),
            FidelityMode::Quick => "quick".into(),
        },
        tcp_tolerance_m: TCP_TOLERANCE_M,
        policies,
    })
}
