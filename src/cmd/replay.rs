//! `d3il replay`: replay an episode open-loop from policy-level actions and
//! print what our simulator does, as JSON (docs/tasks.md).

use anyhow::{bail, Context};
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::TaskId;
use serde::Deserialize;
use serde_json::{json, Value};
use std::collections::BTreeMap;

#[derive(clap::Args)]
pub struct Args {
    /// Task to replay in (avoiding, aligning, pushing, ...).
    #[arg(long)]
    pub task: TaskId,
    /// JSON file `{"context": {...}, "actions": [[...], ...]}`; `-` reads stdin.
    #[arg(long)]
    pub input: String,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ReplayInput {
    #[serde(default)]
    context: Value,
    actions: Vec<Vec<f32>>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let text = if args.input == "-" {
        std::io::read_to_string(std::io::stdin()).context("reading stdin")?
    } else {
        std::fs::read_to_string(&args.input).with_context(|| format!("reading {}", args.input))?
    };
    let out = replay(args.task, &text)?;
    println!("{}", serde_json::to_string(&out)?);
    Ok(())
}

/// Replays `input_json` and returns the output document.
pub fn replay(task: TaskId, input_json: &str) -> anyhow::Result<Value> {
    let input: ReplayInput = serde_json::from_str(input_json).context(
        "the input must be a JSON object {\"context\": ..., \"actions\": [[...], ...]} with numeric action rows",
    )?;
    let loaded = LoadedTask::load(task)?;
    let act_dim = loaded.def.act_dim();
    for (i, a) in input.actions.iter().enumerate() {
        if a.len() != act_dim {
            bail!(
                "actions[{i}] has {} values but task {task} expects {act_dim} ({})",
                a.len(),
                loaded.def.act_meaning()
            );
        }
    }
    let mut env = loaded.env()?;
    let first = env.reset(&input.context).context("field `context`")?;
    let mut observations = vec![first];
    let mut tcp = vec![env.sim.tcp_pos()];
    let mut joints = vec![env.sim.joint_pos()];
    let mut fingers = vec![env.sim.finger_pos()];
    let mut objects: BTreeMap<String, Vec<[f64; 3]>> = BTreeMap::new();
    let record = |env: &d3il_evaluator::tasks::Env,
                  objects: &mut BTreeMap<String, Vec<[f64; 3]>>| {
        for (name, p) in env.objects() {
            objects.entry(name).or_default().push(p);
        }
    };
    record(&env, &mut objects);
    for (i, a) in input.actions.iter().enumerate() {
        let out = env.step(a).with_context(|| format!("actions[{i}]"))?;
        observations.push(out.obs);
        tcp.push(env.sim.tcp_pos());
        joints.push(env.sim.joint_pos());
        fingers.push(env.sim.finger_pos());
        record(&env, &mut objects);
        if out.done {
            break;
        }
    }
    Ok(json!({
        "task": task,
        "observations": observations,
        "tcp": tcp,
        "joints": joints,
        "fingers": fingers,
        "objects": objects,
        "success": env.success(),
        "behaviour": env.behaviour(),
        "steps": env.steps(),
        "done": env.is_done(),
    }))
}
