//! Sharded evaluations from the CLI (docs/cluster.md): the shard half of
//! `d3il eval --shard K/N --json part.json`, and `d3il merge part*.json`,
//! which joins the parts into the result (and table) of a plain `d3il eval`.

use anyhow::{bail, Context};
use d3il_evaluator::eval;
use d3il_evaluator::shard::{self, EvalPart, Shard};
use d3il_protocol::Job;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The part files `d3il eval --shard K/N --json FILE` wrote, one per
    /// shard, in any order.
    #[arg(required = true)]
    pub parts: Vec<PathBuf>,
    /// Write the merged result here (the same format as `d3il eval --json`).
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// `d3il eval --shard K/N`: evaluates one shard and writes its part file.
pub fn run_shard(args: &super::eval::Args, job: &Job, shard: Shard) -> anyhow::Result<()> {
    let Some(path) = &args.json else {
        bail!("--shard {shard} needs --json FILE: the part file `d3il merge` joins with the other shards");
    };
    let mut on_progress = super::eval::progress_printer();
    let part = if args.sandbox {
        // The worker runs the shard (`Job::shard`) and answers with its part.
        let job = Job {
            shard: Some(shard),
            ..job.clone()
        };
        match super::eval::sandboxed(&job, &mut on_progress)? {
            d3il_sandbox::Outcome::Part(p) => *p,
            _ => bail!("the worker answered shard {shard} with a whole result"),
        }
    } else {
        let (task, mut policy, info, opts) = super::eval::load_in_process(args, job)?;
        let (part, t) = eval::evaluate_shard(
            &task,
            policy.as_mut(),
            &info,
            &opts,
            shard,
            &mut on_progress,
        )?;
        super::eval::print_timing(&t);
        part
    };
    println!(
        "task {} shard {shard}: initial states {}..{} of {}, {} rollouts (merge all {} parts with `d3il merge`)",
        part.manifest.task,
        part.contexts[0],
        part.contexts[1],
        part.manifest.n_contexts,
        part.rollouts.len(),
        shard.count
    );
    std::fs::write(path, serde_json::to_vec_pretty(&part)?)
        .with_context(|| format!("writing {}", path.display()))?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut parts = Vec::with_capacity(args.parts.len());
    for path in &args.parts {
        let text = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let part: EvalPart = serde_json::from_slice(&text).with_context(|| {
            format!(
                "{} is not a part file of `d3il eval --shard K/N --json FILE`",
                path.display()
            )
        })?;
        parts.push((path.display().to_string(), part));
    }
    let result = shard::merge(parts)?;
    print!("{}", d3il_tables::summary::metrics_table(&result));
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_vec_pretty(&result)?)
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
