//! Results of one evaluation, and aggregated table cells.

use crate::interval::{IntervalMethod, NoInterval};
use crate::task::{robot_look_note, ObsType, ProtocolKind, RobotLook, RobotLookNote, TaskId};
use serde::{Deserialize, Serialize};

/// Everything needed to know exactly what was measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProtocolManifest {
    pub task: TaskId,
    pub task_version: String,
    pub obs_type: ObsType,
    pub protocol: ProtocolKind,
    /// Image results: how the cameras drew the robot. None for state results
    /// (nothing is drawn) and for image results stored before the look was
    /// recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robot_look: Option<RobotLook>,
    pub mjcf_sha256: String,
    pub initial_states_sha256: String,
    /// File name of the initial-state set (e.g. `pushing-v2.json`); empty in
    /// results stored before the sets were named (all of them used v1).
    #[serde(default)]
    pub initial_states: String,
    pub mujoco_version: String,
    pub evaluator_version: String,
    pub n_contexts: usize,
    pub rollouts_per_context: usize,
    pub max_steps: usize,
    pub policy_sha256: String,
    pub history: usize,
    pub horizon: usize,
    pub execute: usize,
    pub seed: u64,
    /// The policy was deterministic (an ONNX graph without a `noise` input),
    /// so each initial state's rollouts were simulated once and that rollout
    /// recorded under every rollout index: the rollouts of one state are
    /// identical by construction, with the same results as simulating each
    /// (docs/submission.md). Written only when true.
    #[serde(default, skip_serializing_if = "is_false")]
    pub simulated_once: bool,
    /// The build that made the result (CHANGELOG.md); absent in results made
    /// before builds were identified (evaluator 0.1.0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub build: Option<BuildIdentity>,
    /// The robustness track's perturbation this result ran under (suite file
    /// and sha256, axis, level, setting); absent for a plain evaluation,
    /// which is every axis's level 0 (docs/robustness.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub perturbation: Option<crate::perturbation::Perturbation>,
}

/// Which build made a result, beyond `evaluator_version`, `mujoco_version`
/// and `mjcf_sha256`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
pub struct BuildIdentity {
    /// The git commit the binary was built from (`unknown` outside a checkout).
    pub git_commit: String,
    /// The physics fingerprint: the hash of the drift canary's outcomes as
    /// this build computes them (`d3il verify`). Results whose fingerprints
    /// differ are never averaged or ranked together. None when it was not
    /// computed for this result.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub physics_fingerprint: Option<String>,
}

fn is_false(b: &bool) -> bool {
    !*b
}

/// The initial-state sets that are the original D3IL test contexts (decoded
/// from the reference repository's `test_contexts.pkl`; Avoiding has the one
/// fixed start of the original). Every other set is our own sample from the
/// task's context distribution.
pub const ORIGINAL_CONTEXT_SETS: [&str; 4] = [
    "avoiding-v1.json",
    "aligning-v2.json",
    "pushing-v2.json",
    "stacking-v2.json",
];

/// Where the initial states of a result came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum InitialStatesOrigin {
    /// The original D3IL test contexts: comparable to the paper context by context.
    Original,
    /// Our sample from the task's context distribution: comparable to the
    /// paper only in distribution.
    Sample,
}

impl InitialStatesOrigin {
    pub fn label(self) -> &'static str {
        match self {
            InitialStatesOrigin::Original => "the original D3IL test contexts",
            InitialStatesOrigin::Sample => "our sample",
        }
    }
}

impl std::fmt::Display for InitialStatesOrigin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.label())
    }
}

/// The name of the set a result used, from its manifest's `initial_states`
/// (empty in results stored before sets were named: those used v1).
pub fn initial_states_name(task: TaskId, recorded: &str) -> String {
    if recorded.is_empty() {
        format!("{task}-v1.json")
    } else {
        recorded.to_string()
    }
}

impl InitialStatesOrigin {
    /// Where the set of this name comes from.
    pub fn of(set_name: &str) -> Self {
        if ORIGINAL_CONTEXT_SETS.contains(&set_name) {
            InitialStatesOrigin::Original
        } else {
            InitialStatesOrigin::Sample
        }
    }
}

impl ProtocolManifest {
    /// The set's name; results stored before sets were named used v1.
    pub fn initial_states_name(&self) -> String {
        initial_states_name(self.task, &self.initial_states)
    }

    pub fn initial_states_origin(&self) -> InitialStatesOrigin {
        InitialStatesOrigin::of(&self.initial_states_name())
    }

    /// How the robot was drawn, when not as the original draws it.
    pub fn robot_look_note(&self) -> Option<RobotLookNote> {
        robot_look_note(self.obs_type, self.robot_look)
    }

    /// The physics fingerprint of the build that made the result, if recorded.
    pub fn physics_fingerprint(&self) -> Option<&str> {
        self.build
            .as_ref()
            .and_then(|b| b.physics_fingerprint.as_deref())
    }
}

/// A value with its confidence interval, the method that made it, or why
/// there is none (docs/intervals.md).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    pub value: f64,
    /// The interval's ends; both equal to `value` when `no_interval` says
    /// why there is none (read them through [`Estimate::interval`]).
    pub ci_low: f64,
    pub ci_high: f64,
    /// The method of the interval; absent in documents written before 0.5.0,
    /// whose intervals were all the bias-corrected bootstrap.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub method: Option<IntervalMethod>,
    /// Why no interval is given (e.g. 3 initial states).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub no_interval: Option<NoInterval>,
}

impl Estimate {
    /// A value with an interval made by `method`.
    pub fn with_interval(value: f64, ci_low: f64, ci_high: f64, method: IntervalMethod) -> Self {
        Estimate {
            value,
            ci_low,
            ci_high,
            method: Some(method),
            no_interval: None,
        }
    }

    /// A value without an interval, and why.
    pub fn without_interval(value: f64, why: NoInterval) -> Self {
        Estimate {
            value,
            ci_low: value,
            ci_high: value,
            method: None,
            no_interval: Some(why),
        }
    }

    /// The interval's ends, or `None` when there is none.
    pub fn interval(&self) -> Option<(f64, f64)> {
        match self.no_interval {
            Some(_) => None,
            None => Some((self.ci_low, self.ci_high)),
        }
    }

    /// `0.300–0.500` (at `digits` decimals), or the short reason there is no interval.
    pub fn interval_text(&self, digits: usize) -> String {
        match &self.no_interval {
            Some(why) => why.short(),
            None => format!("{:.digits$}–{:.digits$}", self.ci_low, self.ci_high),
        }
    }

    /// What the interval is: its method's name, the reason there is none,
    /// or for documents written before 0.5.0 the method they all had.
    pub fn interval_note(&self) -> String {
        match (&self.no_interval, self.method) {
            (Some(why), _) => why.to_string(),
            (None, Some(m)) => m.name().to_string(),
            (None, None) => "bias-corrected bootstrap (before 0.5.0)".to_string(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub success_rate: Estimate,
    /// H(pi(beta)) over successful rollouts, log base |B|.
    pub behaviour_entropy: Estimate,
    /// E_s0[H(pi(beta|s0))] as the reference computes it.
    pub conditional_entropy: Estimate,
    /// Stacking only: success rates of Stacking-1/2/3 (>= 1, >= 2 boxes
    /// registered at the target, full stack); the same numbers as
    /// `stacking_levels[i].success_rate.value`, kept for results stored before
    /// the levels carried their own entropies.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stacking: Option<[f64; 3]>,
    /// Stacking only: Stacking-1/2/3 each with its own success rate, behaviour
    /// entropy and conditional entropy (docs/original-d3il.md §11.2.7: level X uses the first X
    /// letters of the registration order over the rollouts with that level's
    /// success flag, log base 3 / 6 / 6). The top-level fields above are
    /// Stacking-3's. Absent in results stored before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stacking_levels: Option<[StackingLevel; 3]>,
    /// Mean policy inference time per batched query, milliseconds.
    pub inference_ms: f64,
}

/// One Stacking level's metrics (Stacking-1, -2 or -3).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StackingLevel {
    pub success_rate: Estimate,
    /// H(pi(beta)) of the level's X-box codes over its successful rollouts.
    pub behaviour_entropy: Estimate,
    /// E_s0[H(pi(beta|s0))] of the level's X-box codes, as the reference computes it.
    pub conditional_entropy: Estimate,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ContextResult {
    pub context_index: usize,
    pub success_rate: f64,
    pub conditional_entropy: f64,
    /// Count per behaviour label (label as the reference encodes it, as a string).
    pub behaviours: Vec<(String, usize)>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutRecord {
    pub context_index: usize,
    pub rollout_index: usize,
    pub success: bool,
    /// Behaviour label in the reference encoding (JSON: vector, int or string).
    pub behaviour: serde_json::Value,
    pub steps: usize,
    /// End-effector xy path (Avoiding only), for plotting.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path: Option<Vec<[f32; 2]>>,
    /// Why the rollout was ended early as a failure (e.g. the simulation
    /// became unstable); absent for a rollout that ran its course.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failure: Option<RolloutFailure>,
    /// How the rollout ended; absent in results stored before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ending: Option<crate::rollout::Ending>,
    /// What it did, for replays, videos and pictures
    /// ([`crate::rollout::RolloutTrace`]). Absent in results stored before
    /// traces existed, and in the copies of a rollout simulated once per
    /// initial state (`manifest.simulated_once`): those share the trace of
    /// their state's rollout 0 ([`EvalResult::trace_of`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trace: Option<Box<crate::rollout::RolloutTrace>>,
}

impl RolloutRecord {
    /// The rollout's number in the protocol: initial state × rollouts per
    /// state + index within the state.
    pub fn number(&self, rollouts_per_context: usize) -> usize {
        self.context_index * rollouts_per_context + self.rollout_index
    }
}

/// A rollout ended by the evaluator rather than by the task.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutFailure {
    pub reason: FailureReason,
    /// The simulator's message (e.g. MuJoCo's warning text).
    pub message: String,
    /// Environment step at which it happened.
    pub step: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FailureReason {
    /// A MuJoCo warning (instability, contact buffer overflow, ...) or a
    /// non-finite simulator state: the rollout counts as a failure.
    SimUnstable,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalResult {
    pub manifest: ProtocolManifest,
    pub metrics: Metrics,
    pub per_context: Vec<ContextResult>,
    /// Empty (or absent) in summaries that leave the records out (a stored
    /// robustness summary, docs/measurements).
    #[serde(default)]
    pub rollouts: Vec<RolloutRecord>,
    /// Rollouts ended as failures because the simulation became unstable
    /// (their records carry `failure.reason = sim_unstable`).
    #[serde(default)]
    pub rollouts_ended_unstable: usize,
}

impl EvalResult {
    /// More than half of the rollouts ended with an unstable simulation: the
    /// numbers say more about the simulator than about the policy.
    pub fn mostly_unstable(&self) -> bool {
        2 * self.rollouts_ended_unstable > self.rollouts.len()
    }

    /// Where this result and `other` differ other than in what is measured
    /// (`metrics.inference_ms`, the only timing a result holds); `None` when
    /// they are the same evaluation bit for bit: protocol manifest, every
    /// metric, per-initial-state results and every rollout record with its
    /// trace. Compared as JSON (written round-trip exact), so that NaN
    /// equals NaN. The message names the first differing part.
    pub fn difference_except_timings(&self, other: &EvalResult) -> Option<String> {
        let mut a = self.metrics.clone();
        let mut b = other.metrics.clone();
        a.inference_ms = 0.0;
        b.inference_ms = 0.0;
        let parts: [(&str, String, String); 4] = [
            (
                "protocol manifest",
                json(&self.manifest),
                json(&other.manifest),
            ),
            ("metrics", json(&a), json(&b)),
            (
                "per-initial-state results",
                json(&self.per_context),
                json(&other.per_context),
            ),
            (
                "rollouts ended unstable",
                self.rollouts_ended_unstable.to_string(),
                other.rollouts_ended_unstable.to_string(),
            ),
        ];
        for (what, x, y) in parts {
            if x != y {
                return Some(format!("{what}: {x} vs {y}"));
            }
        }
        if self.rollouts.len() != other.rollouts.len() {
            return Some(format!(
                "{} rollouts vs {}",
                self.rollouts.len(),
                other.rollouts.len()
            ));
        }
        for (x, y) in self.rollouts.iter().zip(&other.rollouts) {
            if json(x) != json(y) {
                return Some(format!(
                    "rollout {} of initial state {}: {} vs {}",
                    x.rollout_index,
                    x.context_index,
                    short(&json(x)),
                    short(&json(y))
                ));
            }
        }
        None
    }

    /// The record of rollout `number` ([`RolloutRecord::number`]).
    pub fn rollout(&self, number: usize) -> Option<&RolloutRecord> {
        let per = self.manifest.rollouts_per_context;
        self.rollouts.iter().find(|r| r.number(per) == number)
    }

    /// Gives every copy of a rollout simulated once per initial state its
    /// state's trace ([`EvalResult::trace_of`]), so that the result reads as
    /// if every rollout had been simulated (tests compare both ways).
    pub fn resolve_traces(&mut self) {
        let traces: Vec<Option<Box<crate::rollout::RolloutTrace>>> = self
            .rollouts
            .iter()
            .map(|r| self.trace_of(r).cloned().map(Box::new))
            .collect();
        for (r, t) in self.rollouts.iter_mut().zip(traces) {
            r.trace = t;
        }
    }

    /// The trace of `record`: its own, or, for a copy of a rollout simulated
    /// once per initial state, the one of its state's rollout 0.
    pub fn trace_of<'a>(
        &'a self,
        record: &'a RolloutRecord,
    ) -> Option<&'a crate::rollout::RolloutTrace> {
        trace_of(&self.manifest, &self.rollouts, record)
    }
}

/// The trace of `record` among `rollouts` (a result's, a part's or any
/// subset holding the state's rollout 0): its own, or, for a copy of a
/// rollout simulated once per initial state, the one of its state's rollout 0.
pub fn trace_of<'a>(
    manifest: &ProtocolManifest,
    rollouts: &'a [RolloutRecord],
    record: &'a RolloutRecord,
) -> Option<&'a crate::rollout::RolloutTrace> {
    if let Some(t) = &record.trace {
        return Some(t);
    }
    if !manifest.simulated_once {
        return None;
    }
    rollouts
        .iter()
        .find(|r| r.context_index == record.context_index && r.rollout_index == 0)
        .and_then(|r| r.trace.as_deref())
}

/// One metric of a paired comparison of two results (A − B).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PairedDifference {
    /// The metric of A and of B, each the mean over the shared initial states.
    pub a: f64,
    pub b: f64,
    /// A − B with its paired bootstrap interval over initial states.
    pub difference: Estimate,
    /// Two-sided p-value of "no difference" (paired by initial state: a
    /// randomisation test that swaps A and B within initial states).
    pub p_value: f64,
    /// The smallest true |A − B| this comparison detects with 80 % power at
    /// the 5 % level, from the paired standard error at this protocol's size.
    pub min_detectable: f64,
}

impl PairedDifference {
    /// What the difference's interval and p-value are, in a sentence (the
    /// CLI and the pages print it).
    pub fn interval_note(&self) -> String {
        match (self.difference.no_interval, self.difference.method) {
            (Some(why), _) => format!("{why}; p from the paired randomisation test"),
            (None, Some(m)) if m.agrees_with_p_value() => format!(
                "interval: the {}, the test whose p-value is shown: 0 is outside it exactly when p < 0.05",
                m.name()
            ),
            (None, Some(m)) => format!(
                "interval: {}; p from the paired randomisation test (the two can disagree)",
                m.name()
            ),
            (None, None) => format!("interval: {}", self.difference.interval_note()),
        }
    }
}

/// A paired comparison of two results on the same task, protocol and initial
/// states (`d3il compare`, `GET /api/v1/compare`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    pub task: TaskId,
    pub protocol: crate::task::ProtocolKind,
    /// The shared initial-state set (its file name when known) and sha256.
    #[serde(default)]
    pub initial_states: String,
    pub initial_states_sha256: String,
    pub n_contexts: usize,
    pub rollouts_per_context: usize,
    pub resamples: usize,
    pub confidence: f64,
    /// Stacking: Stacking-3's.
    pub success_rate: PairedDifference,
    pub conditional_entropy: PairedDifference,
    /// What else differs between A and B, so that the difference is not the
    /// policies' alone: how they observe, how image frames drew the robot.
    /// Empty (and not written) when nothing does.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub caveats: Vec<String>,
}

/// Mean and standard deviation over training seeds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    pub mean: f64,
    pub std: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Source {
    Reported,
    Evaluated,
}

/// One leaderboard/table cell group: a method on a task, observation type and
/// data fraction, aggregated over its training seeds. Produced by the server's
/// store (reported rows from the paper, evaluated rows from results) and
/// consumed by the pages and `d3il tables`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultCell {
    /// Paper table this row belongs to: `main`, `datasize`, `posvel`, `prelim`
    /// (evaluated rows use `main` at fraction 1.0 and `datasize` otherwise).
    pub table: String,
    pub method: String,
    /// The paper's task title, e.g. `Stacking-2 (T5)` or `Arranging (T7)`;
    /// for evaluated rows [`TaskId::title`] (Stacking evaluated rows expand to
    /// `Stacking-1/2/3 (T5)`).
    pub task: String,
    pub obs: ObsType,
    pub data_fraction: f64,
    /// `position`/`velocity` for the posvel table, otherwise None.
    pub control: Option<String>,
    pub source: Source,
    pub success_rate: Stat,
    /// Conditional behaviour entropy (the paper's "Entropy" column).
    pub entropy: Stat,
    pub n_seeds: usize,
    /// As the paper printed them (reported rows only).
    pub bold_success: Option<bool>,
    pub bold_entropy: Option<bool>,
    /// Evaluated rows: which initial states the row used
    /// ([`InitialStatesOrigin::label`]); rows on different sets are separate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_states: Option<String>,
    /// Evaluated image rows whose robot was not drawn as the original draws
    /// it: the look's badge ([`RobotLookNote::badge`], e.g. `primitive
    /// robot`); rows drawn differently are separate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robot_look: Option<String>,
    /// Evaluated rows made by another build than the one showing them: why
    /// (the fingerprints); rows of different builds are separate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub build: Option<String>,
}

/// JSON text of a part [`EvalResult::difference_except_timings`] compares.
fn json<T: Serialize>(v: &T) -> String {
    serde_json::to_string(v).unwrap_or_else(|e| format!("(not serialisable: {e})"))
}

/// The first 300 characters, for messages.
fn short(s: &str) -> String {
    match s.char_indices().nth(300) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_without_stacking_levels_still_parse() {
        // A Stacking result stored before the levels carried their own entropies.
        let old = r#"{"success_rate":{"value":0.4,"ci_low":0.3,"ci_high":0.5},
            "behaviour_entropy":{"value":0.1,"ci_low":0.0,"ci_high":0.2},
            "conditional_entropy":{"value":0.2,"ci_low":0.1,"ci_high":0.3},
            "stacking":[0.9,0.7,0.4],"inference_ms":1.0}"#;
        let m: Metrics = serde_json::from_str(old).unwrap();
        assert_eq!(m.stacking, Some([0.9, 0.7, 0.4]));
        assert_eq!(m.stacking_levels, None);
        // And the levels round-trip when present.
        assert_eq!(m.success_rate.method, None);
        assert_eq!(m.success_rate.interval(), Some((0.3, 0.5)));
        assert_eq!(
            m.success_rate.interval_note(),
            "bias-corrected bootstrap (before 0.5.0)"
        );
        let e = |v| Estimate::with_interval(v, v / 2.0, v, IntervalMethod::KornGraubard);
        let level = |s, b, c| StackingLevel {
            success_rate: e(s),
            behaviour_entropy: e(b),
            conditional_entropy: e(c),
        };
        let m = Metrics {
            stacking_levels: Some([
                level(0.9, 0.5, 0.6),
                level(0.7, 0.3, 0.4),
                level(0.4, 0.1, 0.2),
            ]),
            ..m
        };
        let back: Metrics = serde_json::from_str(&serde_json::to_string(&m).unwrap()).unwrap();
        assert_eq!(back, m);
    }

    #[test]
    fn an_estimate_without_an_interval_says_why_in_json_and_text() {
        let e =
            Estimate::without_interval(2.0 / 3.0, NoInterval::TooFewStates { states: 3, min: 5 });
        let json = serde_json::to_string(&e).unwrap();
        assert!(
            json.contains(r#""no_interval":{"reason":"too_few_states","states":3,"min":5}"#),
            "{json}"
        );
        assert!(!json.contains("method"), "{json}");
        let back: Estimate = serde_json::from_str(&json).unwrap();
        assert_eq!(back, e);
        assert_eq!(back.interval(), None);
        assert_eq!(back.interval_text(3), "no interval (3 states)");
        assert!(back
            .interval_note()
            .contains("3 initial states cannot show"));
        let with = Estimate::with_interval(0.5, 0.25, 0.75, IntervalMethod::SignFlipExact);
        let json = serde_json::to_string(&with).unwrap();
        assert!(json.contains(r#""method":"sign_flip_exact""#), "{json}");
        assert_eq!(with.interval_text(2), "0.25–0.75");
        assert_eq!(with.interval_note(), "inverted sign-flip test (exact)");
    }

    /// Results travel worker → JSON line → server → JSON in SQLite; every f64
    /// must come back with the same bits ("same policy, seed and protocol →
    /// bit-identical results"). serde_json's default float parser gets about
    /// one in ten random values in [0, 1) wrong in the last bit (for example
    /// 0.9856906946328695); the workspace enables `float_roundtrip`.
    #[test]
    fn floats_survive_the_json_round_trip_bit_for_bit() {
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut values = vec![0.9856906946328695, 1.0 / 3.0, 0.1 + 0.2, 5e-324, 1e300];
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            values.push((x >> 11) as f64 / (1u64 << 53) as f64);
        }
        for v in values {
            let e = Estimate::with_interval(v, v / 3.0, v * 7.0, IntervalMethod::ClusterBootstrap);
            let back: Estimate = serde_json::from_str(&serde_json::to_string(&e).unwrap()).unwrap();
            for (a, b) in [
                (back.value, e.value),
                (back.ci_low, e.ci_low),
                (back.ci_high, e.ci_high),
            ] {
                assert_eq!(a.to_bits(), b.to_bits(), "{b:e} came back as {a:e}");
            }
        }
    }
}
