//! `d3il contexts`: generate or verify the fixed initial-state sets.

use anyhow::Context;
use d3il_evaluator::tasks::{contexts, task_def};
use d3il_protocol::TaskId;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub action: Action,
}

#[derive(clap::Subcommand)]
pub enum Action {
    /// Sample a new set from the task's distribution and write it (then record its sha256 in the task's code).
    Generate {
        #[arg(long)]
        task: TaskId,
        /// Seed of the ChaCha8 sampler, recorded in the file.
        #[arg(long)]
        seed: u64,
        /// Number of initial states.
        #[arg(long)]
        count: usize,
        #[arg(long)]
        out: std::path::PathBuf,
    },
    /// Verify the committed set of a task against the hash recorded in the code.
    Verify {
        #[arg(long)]
        task: TaskId,
    },
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.action {
        Action::Generate {
            task,
            seed,
            count,
            out,
        } => {
            let def = task_def(task)?;
            let file = contexts::generate(def.as_ref(), seed, count);
            let bytes = contexts::to_bytes(&file);
            std::fs::write(&out, &bytes).with_context(|| format!("writing {}", out.display()))?;
            println!("{}  {}", contexts::sha256_hex(&bytes), out.display());
        }
        Action::Verify { task } => {
            let set = task_def(task)?.context_set()?;
            println!(
                "{}: {} initial states, sha256 {} (ok)",
                set.name,
                set.len(),
                set.sha256
            );
        }
    }
    Ok(())
}
