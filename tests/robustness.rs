//! The robustness track (issue 40) in the engine and on the command line:
//! level 0 of every axis is the plain evaluation bit for bit, perturbed
//! rollouts replay bit for bit, suites are hash-checked, observation noise
//! reaches the policy's observation (and only its environment part) and
//! latency delays the actions the environment receives by exactly the set
//! number of steps, a fractional one blending them (`latency.rs`: on
//! Stacking the joint increments, the gripper value taken whole).

use d3il_evaluator::eval::{evaluate, sha256_hex, EvalOptions, EvalRun, PolicyInfo};
use d3il_evaluator::perturb::{Active, Suite};
use d3il_evaluator::robustness::{evaluate_suite, plan, SuiteObserver};
use d3il_evaluator::scripted::ScriptedPolicy;
use d3il_evaluator::tasks::LoadedTask;
use d3il_evaluator::trace::{load_task, replay};
use d3il_policy::{ActionChunks, OnnxPolicy, Policy, PolicyError, PolicyShape, Query};
use d3il_protocol::perturbation::{Axis, LevelSetting, Perturbation};
use d3il_protocol::{EvalResult, ObsType, ProtocolKind, TaskId};
use d3il_test_support::{fixture_manifest, fixtures_dir};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, OnceLock};

#[path = "robustness/latency.rs"]
mod latency;

/// What a policy was asked and answered: (rollout id, step) -> (observation
/// row, first action).
type Log = Arc<Mutex<BTreeMap<(u64, u64), (Vec<f32>, Vec<f32>)>>>;

/// Wraps a policy and logs every row it is queried with: the policy "echoes"
/// what it observed into the log.
struct Recorder<P> {
    inner: P,
    log: Log,
}

impl<P: Policy> Policy for Recorder<P> {
    fn shape(&self) -> PolicyShape {
        self.inner.shape()
    }
    fn reset(&mut self, ids: &[u64]) -> Result<(), PolicyError> {
        self.inner.reset(ids)
    }
    fn infer(&mut self, q: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        let out = self.inner.infer(q)?;
        let (s, b) = (self.inner.shape(), q.batch());
        let w = q.obs.len() / b;
        let mut log = self.log.lock().unwrap();
        for r in 0..b {
            let row = q.obs[(r + 1) * w - s.obs_dim..(r + 1) * w].to_vec();
            log.insert(
                (q.rollout_ids[r], q.steps[r]),
                (row, out.action(r, 0).to_vec()),
            );
        }
        Ok(out)
    }
    fn deterministic(&self) -> bool {
        self.inner.deterministic()
    }
}

fn opts() -> EvalOptions {
    EvalOptions {
        protocol: ProtocolKind::Quick,
        bootstrap_resamples: 100,
        max_live: 4,
        ..EvalOptions::default()
    }
}

/// Every task with a scripted expert and the step cap its checks run with:
/// Aligning and Pushing whole episodes, the six other tasks' suites (v1) a
/// few dozen steps (their episodes are 250 to 2000 steps; the level-0
/// identity and the replays hold at every step).
const EXPERTS: &[(TaskId, &str, Option<usize>)] = &[
    (TaskId::Aligning, "aligning:inside", None),
    (TaskId::Pushing, "pushing:mode=0", None),
    (TaskId::Avoiding, "avoiding:all-paths", Some(30)),
    (TaskId::Sorting2, "sorting-2:all-orders", Some(30)),
    (TaskId::Sorting4, "sorting-4:all-orders", Some(30)),
    (TaskId::Sorting6, "sorting-6:all-orders", Some(30)),
    (TaskId::Stacking, "stacking:all-orders", Some(30)),
    (TaskId::Inserting, "inserting:box=g", Some(30)),
];

/// The tests' options with a step cap. A one-variant script is
/// deterministic (simulated once per initial state, `tests/eval/identical_rollouts.rs`);
/// these tests read every rollout's own trace and policy queries, so every
/// rollout is simulated.
fn capped(cap: Option<usize>) -> EvalOptions {
    EvalOptions {
        step_cap: cap,
        simulate_every_rollout: true,
        ..opts()
    }
}

fn info() -> PolicyInfo {
    PolicyInfo {
        sha256: "scripted".into(),
        obs_type: ObsType::State,
    }
}

fn scripted(task: &LoadedTask, name: &str) -> ScriptedPolicy {
    ScriptedPolicy::from_name(name, task.spec()).unwrap()
}

/// The plain evaluation of the scripted expert `name` on `task` under
/// [`capped`]`(cap)`, simulated once for the tests of this file: the
/// level-0 test compares every axis's level 0 with it, the replay test its
/// top levels' traces (both run at once, so the second to ask waits for the
/// first). A fresh policy: the level-0 test shows that an evaluation does
/// not depend on what the policy ran before.
fn plain_evaluation(
    id: TaskId,
    task: &LoadedTask,
    name: &'static str,
    cap: Option<usize>,
) -> Arc<EvalResult> {
    type Key = (String, &'static str, Option<usize>);
    type Slot = Arc<OnceLock<Arc<EvalResult>>>;
    static PLAIN: OnceLock<Mutex<BTreeMap<Key, Slot>>> = OnceLock::new();
    let slot = PLAIN
        .get_or_init(Default::default)
        .lock()
        .unwrap()
        .entry((id.to_string(), name, cap))
        .or_default()
        .clone();
    slot.get_or_init(|| {
        let mut policy = scripted(task, name);
        let (r, _) = evaluate(task, &mut policy, &info(), &capped(cap), EvalRun::all()).unwrap();
        Arc::new(r)
    })
    .clone()
}

/// A perturbation of `axis` with `setting`, against the task's committed suite.
fn perturbation(task: TaskId, axis: Axis, setting: LevelSetting) -> Perturbation {
    let suite = Suite::for_task(task).unwrap();
    Perturbation {
        suite: suite.name,
        suite_sha256: suite.sha256,
        axis,
        level: 1,
        setting,
    }
}

/// The result as JSON without what a perturbed run legitimately adds (the
/// manifest's perturbation) and the measured inference time.
fn comparable(r: &EvalResult) -> serde_json::Value {
    let mut v = serde_json::to_value(r).unwrap();
    v["metrics"]["inference_ms"] = serde_json::Value::Null;
    v["manifest"]
        .as_object_mut()
        .unwrap()
        .remove("perturbation");
    v
}

/// Every axis at magnitude zero (level 0) runs through the perturbation
/// hooks (shifted contexts, noise, delay line, a recompiled and re-massed
/// model) and must give the plain evaluation bit for bit: records, traces,
/// metrics. A scripted expert (every rollout simulated) and a deterministic
/// ONNX policy (simulated once per state; under noise every rollout).
#[test]
fn level_zero_of_every_axis_is_the_plain_evaluation_bit_for_bit() {
    let zero = [
        (
            Axis::StartShift,
            LevelSetting {
                widen: Some(0.0),
                ..Default::default()
            },
        ),
        (
            Axis::ObsNoise,
            LevelSetting {
                position_m: Some(0.0),
                angle_rad: Some(0.0),
                ..Default::default()
            },
        ),
        (
            Axis::Latency,
            LevelSetting {
                steps: Some(0),
                ..Default::default()
            },
        ),
        (
            Axis::Dynamics,
            LevelSetting {
                mass: Some(1.0),
                friction: Some(1.0),
                ..Default::default()
            },
        ),
    ];
    for &(id, name, cap) in EXPERTS {
        let task = LoadedTask::load(id).unwrap();
        let mut policy = scripted(&task, name);
        let opts = capped(cap);
        let plain = plain_evaluation(id, &task, name, cap);
        // The axes of the task's suite (Avoiding's has no start_shift and
        // no dynamics: a fixed start, no movable object).
        let suite = Suite::for_task(id).unwrap();
        let has = |axis: &Axis| suite.file.axes.iter().any(|a| a.axis == *axis);
        for (axis, setting) in zero.iter().filter(|(axis, _)| has(axis)) {
            let p = perturbation(id, *axis, setting.clone());
            let (r, _) = evaluate(
                &task,
                &mut policy,
                &info(),
                &opts,
                EvalRun::all().perturbed(&p),
            )
            .unwrap();
            assert_eq!(r.manifest.perturbation.as_ref(), Some(&p));
            assert_eq!(
                comparable(&r),
                comparable(&plain),
                "{id} {axis} at level 0 differs from the plain evaluation"
            );
        }
    }
    // A deterministic ONNX policy: simulated once per state, except under
    // noise, where every rollout is simulated and still equal.
    let task = LoadedTask::load(TaskId::Aligning).unwrap();
    let bytes = std::fs::read(fixtures_dir().join("aligning_mlp.onnx")).unwrap();
    let mut policy =
        OnnxPolicy::load(&bytes, &fixture_manifest("aligning_mlp"), &task.spec(), 0).unwrap();
    let info = PolicyInfo {
        sha256: sha256_hex(&bytes),
        obs_type: ObsType::State,
    };
    let (mut plain, _) = evaluate(&task, &mut policy, &info, &opts(), EvalRun::all()).unwrap();
    assert!(plain.manifest.simulated_once);
    plain.resolve_traces();
    for (axis, setting) in &zero {
        let p = perturbation(TaskId::Aligning, *axis, setting.clone());
        let (mut r, _) = evaluate(
            &task,
            &mut policy,
            &info,
            &opts(),
            EvalRun::all().perturbed(&p),
        )
        .unwrap();
        assert_eq!(r.manifest.simulated_once, *axis != Axis::ObsNoise);
        r.resolve_traces();
        let mut r = comparable(&r);
        let mut plain = comparable(&plain);
        for v in [&mut r, &mut plain] {
            v["manifest"]
                .as_object_mut()
                .unwrap()
                .remove("simulated_once");
        }
        assert_eq!(r, plain, "aligning_mlp {axis} at level 0 differs");
    }
}

/// The top level of every axis of both suites: each perturbed rollout
/// replays bit for bit from its record and the manifest's perturbation
/// (shifted start, re-massed model; noise and latency are in the actions
/// the record holds), and a manifest naming another suite hash is refused.
#[test]
fn perturbed_rollouts_replay_bit_for_bit() {
    for &(id, name, cap) in [
        (TaskId::Aligning, "aligning:inside", None),
        (TaskId::Pushing, "pushing:all-modes", None),
    ]
    .iter()
    .chain(&EXPERTS[2..])
    {
        let task = LoadedTask::load(id).unwrap();
        let mut policy = scripted(&task, name);
        let opts = capped(cap);
        let suite = Suite::for_task(id).unwrap();
        let mut plain_steps = None;
        // The state suite's axes (the image axes are in the image suite,
        // tests/eval/robustness_image.rs; Avoiding has no start_shift and no
        // dynamics).
        let axes: Vec<Axis> = suite.file.axes.iter().map(|a| a.axis).collect();
        assert_eq!(axes.len(), if id == TaskId::Avoiding { 2 } else { 4 });
        for axis in axes {
            let p = suite
                .perturbations()
                .into_iter()
                .rev()
                .find(|p| p.axis == axis)
                .unwrap();
            let (r, _) = evaluate(
                &task,
                &mut policy,
                &info(),
                &opts,
                EvalRun::all().perturbed(&p),
            )
            .unwrap();
            let replay_task = load_task(&r.manifest).unwrap();
            // The first and the last rollout of the level (first state,
            // last state): a replay costs what the rollout cost, and the
            // others are the same replay on the states between.
            let last = r.rollouts.len() - 1;
            for record in [&r.rollouts[0], &r.rollouts[last]] {
                let trace = r.trace_of(record).unwrap();
                let check =
                    replay(&replay_task, &r.manifest, record, trace, &mut |_| Ok(())).unwrap();
                assert!(
                    check.replays(),
                    "{id} {axis} rollout {}: {:?}",
                    record.number(r.manifest.rollouts_per_context),
                    check.differences
                );
            }
            // The perturbation did something: the rollouts are not the plain ones.
            let steps: Vec<usize> = r.rollouts.iter().map(|x| x.steps).collect();
            let digests: Vec<String> = r
                .rollouts
                .iter()
                .map(|x| {
                    x.trace
                        .as_ref()
                        .map(|t| t.digests.clone())
                        .unwrap_or_default()
                })
                .collect();
            let plain = plain_steps.get_or_insert_with(|| {
                plain_evaluation(id, &task, name, cap)
                    .rollouts
                    .iter()
                    .map(|x| {
                        x.trace
                            .as_ref()
                            .map(|t| t.digests.clone())
                            .unwrap_or_default()
                    })
                    .collect::<Vec<_>>()
            });
            // Avoiding's expert steers on the previous command (exact), not
            // on the noisy measured TCP: its actions, hence its rollouts, are
            // the plain ones under noise (docs/robustness.md).
            if (id, axis) == (TaskId::Avoiding, Axis::ObsNoise) {
                assert_eq!(&digests, plain, "{id} {axis}");
            } else {
                assert_ne!(&digests, plain, "{id} {axis}: nothing changed ({steps:?})");
            }
            // Replaying without the perturbation (another suite hash) is refused.
            let mut forged = r.manifest.clone();
            if let Some(p) = forged.perturbation.as_mut() {
                p.suite_sha256 = "0".repeat(64);
            }
            let e = load_task(&forged).err().expect("refused").to_string();
            assert!(
                e.contains(&"0".repeat(64)) && e.contains(&suite.sha256),
                "{e}"
            );
        }
    }
}

/// Observation noise: the policy's first observation (the reset state, the
/// same with and without noise) differs from the plain one by exactly the
/// keyed draws on the environment part, never on the previous command; over
/// every step the position noise has about the level's deviation.
#[test]
fn observation_noise_reaches_the_policy_and_only_the_environment_part() {
    let id = TaskId::Pushing;
    let task = LoadedTask::load(id).unwrap();
    let run = |p: Option<&Perturbation>| {
        let log: Log = Default::default();
        let mut policy = Recorder {
            inner: scripted(&task, "pushing:all-modes"),
            log: log.clone(),
        };
        match p {
            Some(p) => evaluate(
                &task,
                &mut policy,
                &info(),
                &opts(),
                EvalRun::all().perturbed(p),
            ),
            None => evaluate(&task, &mut policy, &info(), &opts(), EvalRun::all()),
        }
        .unwrap();
        let seen = log.lock().unwrap().clone();
        seen
    };
    let plain = run(None);
    let p = perturbation(
        id,
        Axis::ObsNoise,
        LevelSetting {
            position_m: Some(0.01),
            angle_rad: Some(0.2),
            ..Default::default()
        },
    );
    let noisy = run(Some(&p));
    let active = Active::new(&p, id).unwrap();
    let noise = active.noise.as_ref().unwrap();
    let cmd = task.def.cmd_dim();
    let mut starts = 0;
    for ((rollout, step), (obs, _)) in noisy.iter().filter(|((_, s), _)| *s == 0) {
        let (clean, _) = &plain[&(*rollout, *step)];
        let mut expected = clean.clone();
        noise.apply(0, *rollout, 0, &mut expected);
        assert_eq!(obs, &expected, "rollout {rollout}: not the keyed noise");
        assert_eq!(obs[..cmd], clean[..cmd], "the previous command got noise");
        assert!(obs[cmd..].iter().zip(&clean[cmd..]).all(|(a, b)| a != b));
        starts += 1;
    }
    assert_eq!(starts, 6, "quick protocol: 3 states × 2 rollouts");
    // Over all steps: the box positions' noise has about the set deviation
    // (the observation is the true one plus noise; compare with the noise
    // re-drawn on zeros).
    let mut sq = 0.0;
    let mut n = 0;
    for (rollout, step) in noisy.keys() {
        let mut z = vec![0.0f32; task.spec().obs_dim];
        noise.apply(0, *rollout, *step, &mut z);
        for v in &z[cmd..cmd + 4] {
            sq += (*v as f64).powi(2);
            n += 1;
        }
    }
    let sd = (sq / n as f64).sqrt();
    assert!(
        (sd - 0.01).abs() < 0.001,
        "position noise sd {sd} over {n} draws"
    );
}

/// The command line: `d3il eval --suite robustness` says up front how many
/// rollouts it runs, prints a table per axis with paired drops, writes a
/// document whose level 0 is `d3il eval --json`'s result bit for bit (but
/// for the measured inference time), and `d3il replay --level` replays a
/// perturbed rollout from it.
#[test]
fn the_cli_runs_the_suite_and_its_rollouts_replay() {
    use std::process::Command;
    let dir = std::env::temp_dir().join(format!("d3il-robustness-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (doc, plain) = (dir.join("r.json"), dir.join("p.json"));
    let d3il = env!("CARGO_BIN_EXE_d3il");
    let common = [
        "eval",
        "--task",
        "aligning",
        "--policy",
        "scripted:aligning:inside",
        "--protocol",
        "quick",
    ];
    let out = Command::new(d3il)
        .args(common)
        .args(["--suite", "robustness", "--json"])
        .arg(&doc)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let first = stdout.lines().next().unwrap();
    // The current suite (v2); quick protocol: 3 states × 2 rollouts a level.
    // The one-variant script is deterministic: each state simulated once,
    // but every rollout under observation noise.
    let perturbations = Suite::for_task(TaskId::Aligning).unwrap().perturbations();
    let n_levels = perturbations.len();
    let noisy = perturbations
        .iter()
        .filter(|p| p.axis == Axis::ObsNoise)
        .count();
    let rollouts = 6 * (n_levels + 1);
    let simulated = 6 * noisy + 3 * (n_levels + 1 - noisy);
    assert!(
        first.contains(&format!(
            "level 0 and {n_levels} perturbed levels on 4 axes"
        )) && first.contains(&format!(
            "{rollouts} rollouts recorded, {simulated} simulated"
        )),
        "{first}"
    );
    for axis in ["start_shift", "obs_noise", "latency", "dynamics"] {
        assert!(stdout.contains(&format!("\n{axis}: score ")), "{stdout}");
    }
    assert!(stdout.contains("overall robustness score"), "{stdout}");
    let out = Command::new(d3il)
        .args(common)
        .arg("--json")
        .arg(&plain)
        .output()
        .unwrap();
    assert!(out.status.success());
    let read = |p: &std::path::Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
    };
    let mut control = read(&doc)["control"].clone();
    let mut plain = read(&plain);
    for v in [&mut control, &mut plain] {
        v["metrics"]["inference_ms"] = serde_json::Value::Null;
    }
    assert_eq!(control, plain, "level 0 is not the plain evaluation");
    let levels = read(&doc)["levels"].as_array().unwrap().len();
    assert_eq!(levels, n_levels);
    for level in ["dynamics/4", "start_shift/3", "latency/0", "latency/1"] {
        replays(&doc, level, 3);
    }
    let out = replay_level(&doc, "latency/9", 0);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no level 9 of latency"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `d3il replay --result FILE --level LEVEL --rollout N`.
fn replay_level(file: &std::path::Path, level: &str, rollout: usize) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_d3il"))
        .args(["replay", "--result"])
        .arg(file)
        .args(["--level", level, "--rollout", &rollout.to_string()])
        .output()
        .unwrap()
}

/// Rollout `rollout` of `level` in `file` replays bit for bit.
fn replays(file: &std::path::Path, level: &str, rollout: usize) {
    d3il_test_support::succeeded(&replay_level(file, level, rollout), level);
}

struct Quiet;
impl SuiteObserver for Quiet {
    fn progress(&mut self, _: usize, _: usize) {}
}

/// Runs `task`'s whole current suite through `evaluate_suite` (every rollout
/// capped at `cap` steps), writes the document and replays rollout 1 of each
/// of `levels` (`AXIS/N`; `AXIS/top` is the axis's last level) with
/// `d3il replay --level`.
fn suite_replays_on_the_command_line(id: TaskId, script: &str, cap: usize, levels: &[&str]) {
    let task = LoadedTask::load(id).unwrap();
    let mut policy = scripted(&task, script);
    let suite = Suite::for_task(id).unwrap();
    let o = capped(Some(cap));
    let plan = plan(&task, &policy, &o, &suite).unwrap();
    let doc = evaluate_suite(&task, &mut policy, &info(), &o, &suite, &plan, &mut Quiet).unwrap();
    assert_eq!(doc.levels.len(), suite.perturbations().len());
    let dir = std::env::temp_dir().join(format!(
        "d3il-robustness-{}-{}",
        id.slug(),
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("r.json");
    std::fs::write(&file, serde_json::to_vec(&doc).unwrap()).unwrap();
    for level in levels {
        let level = match level.strip_suffix("/top") {
            Some(axis) => {
                let a = suite.file.axes.iter().find(|a| a.axis.to_string() == axis);
                format!("{axis}/{}", a.unwrap().levels.len())
            }
            None => level.to_string(),
        };
        replays(&file, &level, 1);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A new task's suite end to end: Sorting-2's whole suite (v1; a step cap)
/// through `evaluate_suite`, and its perturbed rollouts (start shift of the
/// permuted poses, the platform's friction, latency, noise) replay bit for
/// bit with `d3il replay --level`.
#[test]
fn a_sorting_suite_runs_and_its_perturbed_rollouts_replay_on_the_command_line() {
    suite_replays_on_the_command_line(
        TaskId::Sorting2,
        "sorting-2:all-orders",
        30,
        &[
            "start_shift/top",
            "dynamics/top",
            "latency/top",
            "obs_noise/top",
        ],
    );
}

/// Stacking's suite (v2) end to end, a few steps a rollout: its fractional
/// latency levels (0.5 and 0.9 steps: the joint increments blended, the
/// gripper value whole) and its last one (1.5 steps) replay bit for bit with
/// `d3il replay --level`.
#[test]
fn stackings_fractional_latency_levels_replay_on_the_command_line() {
    let suite = Suite::for_task(TaskId::Stacking).unwrap();
    let latency = suite.file.axes.iter().find(|a| a.axis == Axis::Latency);
    let fractional = latency
        .unwrap()
        .levels
        .iter()
        .filter(|l| l.fraction.is_some())
        .count();
    assert!(fractional >= 2, "{}: fractional latency levels", suite.name);
    suite_replays_on_the_command_line(
        TaskId::Stacking,
        "stacking:all-orders",
        12,
        &["latency/1", "latency/2", "latency/top"],
    );
}
