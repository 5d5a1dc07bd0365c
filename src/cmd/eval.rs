//! `d3il eval`: run a policy on a task under the paper's (or the quick)
//! protocol, with a progress bar, a metrics table and a JSON record.
//! (The flags and the job they make are `crate::common::evaluation`'s, shared
//! with the commands that evaluate too.)

use crate::common::build::this_build;
use crate::common::evaluation::{
    build_job, load_then_fingerprint, print_timing, progress_printer, sandboxed, EvalArgs,
};
use anyhow::{bail, Context};
use d3il_evaluator::eval;
use d3il_evaluator::shard::Shard;
use d3il_protocol::{Job, JobKind};

/// `d3il eval`'s flags (main.rs names every command's flags `Args`).
pub use crate::common::evaluation::EvalArgs as Args;

/// A plain evaluation (`--suite` runs go to `robustness::run`, see main.rs).
pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let mut job = build_job(&args)?;
    if let Some(shard) = args.shard {
        return run_shard(&args, &mut job, shard);
    }
    let mut on_progress = progress_printer();
    let result = if args.sandbox {
        job.build = Some(this_build()?);
        match sandboxed(&job, &mut on_progress)? {
            d3il_sandbox::Outcome::Completed(r) => *r,
            _ => bail!("the worker answered a whole evaluation with a shard's part"),
        }
    } else {
        let (task, mut policy, info, opts) = load_then_fingerprint(&args, &mut job)?;
        let run = eval::EvalRun::all().counting(&mut on_progress);
        let (r, t) = eval::evaluate(&task, policy.as_mut(), &info, &opts, run)?;
        print_timing(&t);
        r
    };
    print!("{}", d3il_tables::summary::metrics_table(&result));
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_vec_pretty(&result)?)
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// `d3il eval --shard K/N`: evaluates one shard and writes its part file.
pub fn run_shard(args: &EvalArgs, job: &mut Job, shard: Shard) -> anyhow::Result<()> {
    let Some(path) = &args.json else {
        bail!("--shard {shard} needs --json FILE: the part file `d3il merge` joins with the other shards");
    };
    let mut on_progress = progress_printer();
    let part = if args.sandbox {
        job.build = Some(this_build()?);
        // The worker runs the shard (`JobKind::Shard`) and answers with its part.
        let job = Job {
            kind: JobKind::Shard(shard),
            ..job.clone()
        };
        match sandboxed(&job, &mut on_progress)? {
            d3il_sandbox::Outcome::Part(p) => *p,
            _ => bail!("the worker answered shard {shard} with a whole result"),
        }
    } else {
        let (task, mut policy, info, opts) = load_then_fingerprint(args, job)?;
        let run = eval::EvalRun::shard(shard).counting(&mut on_progress);
        let (part, t) = eval::evaluate(&task, policy.as_mut(), &info, &opts, run)?;
        print_timing(&t);
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
