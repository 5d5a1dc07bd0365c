//! Results with rollout endings and traces, as a worker stores them since
//! issue 31, and as results stored before (no endings, no traces).
#![allow(dead_code)]

use d3il_protocol::rollout::TraceBuilder;
use d3il_protocol::{Ending, EvalResult, ProtocolKind, RolloutTrace};
use d3il_test_support::{pushing_result, SynthRollout};

/// Steps of a rollout that the task ended before the limit.
pub const SHORT: usize = 60;

/// A small trace of `steps` steps for rollout (c, i): actions
/// `[k / 1000, c + i / 100]`, the TCP moving up x, one box.
pub fn trace(c: usize, i: usize, steps: usize) -> RolloutTrace {
    let boxes = |k: usize| {
        vec![(
            "box".to_string(),
            [0.4 + 0.001 * k as f64, -0.1 + 0.01 * c as f64, 0.02],
        )]
    };
    let tcp = |k: usize| [0.35 + 0.001 * k as f64, 0.02 * i as f64 - 0.1, 0.12];
    let mut b = TraceBuilder::start(2, tcp(0), boxes(0), vec![]);
    for k in 1..=steps {
        let action = [k as f32 / 1000.0, c as f32 + i as f32 / 100.0];
        b.push_step(&action, k as u32, tcp(k), &boxes(k));
    }
    b.finish(boxes(steps))
}

/// The action rows [`trace`] packs.
pub fn actions(c: usize, i: usize, steps: usize) -> Vec<Vec<f32>> {
    (1..=steps)
        .map(|k| vec![k as f32 / 1000.0, c as f32 + i as f32 / 100.0])
        .collect()
}

/// How rollout (c, i) of [`traced_result`] goes: success unless (c + i) % 3
/// == 0; (4, 2) becomes unstable; behaviour i % 2.
pub fn outcome(c: usize, i: usize) -> SynthRollout {
    SynthRollout {
        success: !(c + i).is_multiple_of(3),
        label: i % 2,
        unstable: c == 4 && i == 2,
    }
}

/// A Pushing paper-protocol result (30 states × 16 rollouts, max 400 steps)
/// with endings and traces: successes end after [`SHORT`] steps, failures of
/// even states run to the limit, of odd states are ended by the task early.
/// With `simulated_once`, each state's rollouts are its rollout 0 (outcome
/// of (c, 0)) and only rollout 0 carries the trace.
pub fn traced_result(simulated_once: bool) -> EvalResult {
    let synth = move |c: usize, i: usize| outcome(c, if simulated_once { 0 } else { i });
    let mut r = pushing_result(ProtocolKind::Paper, synth);
    r.manifest.simulated_once = simulated_once;
    for rec in &mut r.rollouts {
        let (c, i) = (rec.context_index, rec.rollout_index);
        let ending = if rec.failure.is_some() {
            Ending::SimUnstable
        } else if rec.success {
            Ending::TaskSuccess
        } else if c % 2 == 0 {
            Ending::TimeLimit
        } else {
            Ending::TaskEnded
        };
        rec.steps = match ending {
            Ending::TimeLimit => 400,
            Ending::SimUnstable => 17,
            _ => SHORT,
        };
        rec.ending = Some(ending);
        let traced_index = if simulated_once { 0 } else { i };
        if i == traced_index {
            rec.trace = Some(Box::new(trace(c, i, rec.steps)));
        }
    }
    r
}

/// The same rollouts as stored before endings and traces existed.
pub fn old_result() -> EvalResult {
    pushing_result(ProtocolKind::Paper, outcome)
}
