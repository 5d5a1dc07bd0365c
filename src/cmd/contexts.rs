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
        /// Task: avoiding, aligning, pushing, sorting-2/4/6, stacking, inserting.
        #[arg(long)]
        task: TaskId,
        /// Seed of the ChaCha8 sampler, recorded in the file.
        #[arg(long)]
        seed: u64,
        /// Number of initial states.
        #[arg(long)]
        count: usize,
        /// Where to write the set (e.g. assets/contexts/pushing-v3.json).
        #[arg(long)]
        out: std::path::PathBuf,
    },
    /// Make a set from the original D3IL test contexts (`{"source", "contexts"}`
    /// as in shared/reference-contexts), same order; every context is checked by
    /// resetting the task's environment to it. Then record its sha256 in the task's code.
    Import {
        /// Task: avoiding, aligning, pushing, sorting-2/4/6, stacking, inserting.
        #[arg(long)]
        task: TaskId,
        /// The decoded reference file, e.g. shared/reference-contexts/pushing.json.
        #[arg(long)]
        from: std::path::PathBuf,
        /// Version of the new set, e.g. v2.
        #[arg(long)]
        version: String,
        /// Where to write the set (e.g. assets/contexts/pushing-v2.json).
        #[arg(long)]
        out: std::path::PathBuf,
    },
    /// Verify the committed sets of a task (the one in use and the older ones
    /// that stored results refer to) against the hashes recorded in the code.
    Verify {
        /// Task: avoiding, aligning, pushing, sorting-2/4/6, stacking, inserting.
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
        Action::Import {
            task,
            from,
            version,
            out,
        } => {
            let text = std::fs::read_to_string(&from)
                .with_context(|| format!("reading {}", from.display()))?;
            let reference: contexts::ReferenceContexts = serde_json::from_str(&text)
                .with_context(|| {
                    format!(
                        "{} is not a reference context file ({{\"source\": ..., \"contexts\": [...]}})",
                        from.display()
                    )
                })?;
            let task_loaded = d3il_evaluator::tasks::LoadedTask::load(task)?;
            let mut env = task_loaded.env()?;
            for (i, c) in reference.contexts.iter().enumerate() {
                env.reset(c)
                    .with_context(|| format!("context {i} of {}", from.display()))?;
            }
            let file = contexts::import(task, &version, reference);
            let bytes = contexts::to_bytes(&file);
            std::fs::write(&out, &bytes).with_context(|| format!("writing {}", out.display()))?;
            println!("{}  {}", contexts::sha256_hex(&bytes), out.display());
        }
        Action::Verify { task } => {
            let def = task_def(task)?;
            let in_use = def.context_set()?.name;
            for set in def.context_sets()? {
                println!(
                    "{}: {} initial states, sha256 {} (ok){}",
                    set.name,
                    set.len(),
                    set.sha256,
                    if set.name == in_use { ", in use" } else { "" }
                );
            }
        }
    }
    Ok(())
}
