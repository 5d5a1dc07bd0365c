//! `d3il bench robustness`: what a robustness evaluation costs per rollout
//! against a plain one. The scripted Aligning expert
//! (every rollout simulated) runs the plain protocol, then the whole suite
//! (level 0 and every level, `d3il_evaluator::robustness::evaluate_suite`);
//! the cost is compared per env step simulated, since perturbed rollouts that
//! fail run longer than the plain ones. It should be the same physics floor
//! (ratio near 1): the perturbations add a recompiled model per dynamics
//! level, noise draws and a delay line, nothing per physics step.

use d3il_evaluator::eval::{self, EvalOptions, PolicyInfo};
use d3il_evaluator::robustness::{self, SuiteObserver};
use d3il_evaluator::scripted::ScriptedPolicy;
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::{EvalResult, ObsType, ProtocolKind, SuiteName, TaskId};
use std::time::Instant;

struct Quiet;

impl SuiteObserver for Quiet {
    fn progress(&mut self, _done: usize, _total: usize) {}
}

fn steps(r: &EvalResult) -> usize {
    r.rollouts.iter().map(|x| x.steps).sum()
}

pub fn run(protocol: ProtocolKind, step_cap: Option<usize>) -> anyhow::Result<()> {
    let task = LoadedTask::load(TaskId::Aligning)?;
    let info = PolicyInfo {
        sha256: "scripted".into(),
        obs_type: ObsType::State,
    };
    // A one-variant script is deterministic: without this the engine would
    // simulate one rollout per state and the bench would not measure the
    // cost per rollout.
    let opts = EvalOptions {
        protocol,
        step_cap,
        simulate_every_rollout: true,
        ..EvalOptions::default()
    };
    let mut policy = ScriptedPolicy::from_name("aligning:inside", task.spec())?;
    let t = Instant::now();
    let (plain, _) = eval::evaluate(&task, &mut policy, &info, &opts, eval::EvalRun::all())?;
    let plain_s = t.elapsed().as_secs_f64();
    let suite = robustness::suite_for(SuiteName::Robustness, TaskId::Aligning, ObsType::State)?;
    let mut policy = ScriptedPolicy::from_name("aligning:inside", task.spec())?;
    let plan = robustness::plan(&task, &policy, &opts, &suite)?;
    println!(
        "robustness bench: aligning, scripted:aligning:inside, {} protocol, suite {}: plain {} rollouts; suite {} rollouts recorded, {} simulated",
        protocol.as_str(),
        suite.name,
        plain.rollouts.len(),
        plan.recorded,
        plan.simulated
    );
    let t = Instant::now();
    let doc =
        robustness::evaluate_suite(&task, &mut policy, &info, &opts, &suite, &plan, &mut Quiet)?;
    let suite_s = t.elapsed().as_secs_f64();
    let plain_steps = steps(&plain);
    let suite_steps =
        steps(&doc.control) + doc.levels.iter().map(|l| steps(&l.result)).sum::<usize>();
    let per = |s: f64, n: usize| 1e3 * s / n.max(1) as f64;
    println!(
        "plain: {plain_s:.1} s, {} rollouts, {plain_steps} env steps: {:.1} ms per rollout, {:.3} ms per env step",
        plain.rollouts.len(),
        per(plain_s, plain.rollouts.len()),
        per(plain_s, plain_steps)
    );
    println!(
        "suite: {suite_s:.1} s, {} rollouts, {suite_steps} env steps: {:.1} ms per rollout, {:.3} ms per env step (metrics and bootstraps of {} levels included)",
        plan.simulated,
        per(suite_s, plan.simulated),
        per(suite_s, suite_steps),
        doc.levels.len() + 1
    );
    println!(
        "robustness: cost per env step against a plain evaluation, ratio {:.2} (per rollout {:.2})",
        per(suite_s, suite_steps) / per(plain_s, plain_steps),
        per(suite_s, plan.simulated) / per(plain_s, plain.rollouts.len())
    );
    Ok(())
}
