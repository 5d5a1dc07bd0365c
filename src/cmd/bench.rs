//! `d3il bench <which>`: benchmarks that print rates and the ratio the issue
//! tracks on their last line. Speed goals live here, never in tests.

use anyhow::bail;
use d3il_evaluator::tasks::avoiding::AvoidingScript;
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::TaskId;
use serde_json::Value;
use std::time::Instant;

#[derive(clap::Args)]
pub struct Args {
    /// Which benchmark: `physics`.
    pub which: String,
    /// Env steps to run (physics).
    #[arg(long, default_value_t = 3000)]
    pub steps: usize,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.which.as_str() {
        "physics" => physics(args.steps),
        other => bail!("unknown benchmark `{other}`; available: physics"),
    }
}

/// Controlled stepping of the Avoiding scene (IK + PD + finger law every
/// substep) versus raw `mj_step` replaying the same controls on the same model.
fn physics(env_steps: usize) -> anyhow::Result<()> {
    let task = LoadedTask::load(TaskId::Avoiding)?;
    let mut env = task.env()?;
    let paths: Vec<AvoidingScript> = (0..24).filter_map(AvoidingScript::new).collect();
    let substeps = task.def.n_substeps();

    // Controlled run, recording the controls of every substep for the raw run.
    let mut episode = 0;
    env.reset(&Value::Null)?;
    let start = Instant::now();
    let mut done_steps = 0;
    while done_steps < env_steps {
        let a = paths[episode % paths.len()].act(&env.policy_obs());
        let out = env.step(&a)?;
        done_steps += 1;
        if out.done {
            episode += 1;
            env.reset(&Value::Null)?;
        }
    }
    let controlled = start.elapsed().as_secs_f64();

    // Record every substep's controls of the same episodes (outside the timed region).
    episode = 0;
    let mut recorded = 0;
    let mut ctrl_log: Vec<Vec<[f64; 9]>> = Vec::new();
    env.sim.ctrl_recorder = Some(Vec::new());
    env.reset(&Value::Null)?;
    while recorded < env_steps {
        let a = paths[episode % paths.len()].act(&env.policy_obs());
        let out = env.step(&a)?;
        recorded += 1;
        if out.done || recorded == env_steps {
            episode += 1;
            let mut log = env
                .sim
                .ctrl_recorder
                .replace(Vec::new())
                .unwrap_or_default();
            // The reset's own hold substep is not part of the env steps.
            log.remove(0);
            ctrl_log.push(log);
            env.reset(&Value::Null)?;
        }
    }
    let actuators = task.ids.actuators;

    // Raw mj_step over the same number of physics steps, same model, same starts.
    let mut raw_env = task.env()?;
    let start = Instant::now();
    let mut raw_steps = 0;
    'outer: for ep in &ctrl_log {
        raw_env.reset(&Value::Null)?;
        for ctrl in ep {
            let c = raw_env.sim.data.ctrl_mut();
            for (k, &a) in actuators.iter().enumerate() {
                c[a] = ctrl[k];
            }
            raw_env.sim.data.step()?;
            raw_steps += 1;
            if raw_steps >= env_steps * substeps {
                break 'outer;
            }
        }
    }
    let raw = start.elapsed().as_secs_f64();

    let physics_steps = (env_steps * substeps) as f64;
    let ctrl_rate = physics_steps / controlled;
    let raw_rate = raw_steps as f64 / raw;
    println!("avoiding scene, {env_steps} env steps x {substeps} substeps, scripted paths");
    println!(
        "controlled: {:.0} env steps/s ({:.0} physics steps/s, IK + PD + fingers every substep)",
        env_steps as f64 / controlled,
        ctrl_rate
    );
    println!(
        "raw mj_step: {:.0} physics steps/s (same model, recorded controls)",
        raw_rate
    );
    println!(
        "ratio controlled/raw (physics steps per second): {:.3}",
        ctrl_rate / raw_rate
    );
    Ok(())
}
