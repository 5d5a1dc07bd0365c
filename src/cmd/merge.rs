//! `d3il merge part*.json` (docs/cluster.md): joins the part files of
//! `d3il eval --shard K/N --json part.json` (eval.rs) into the result (and
//! table) of a plain `d3il eval`.

use anyhow::Context;
use d3il_evaluator::shard::{self, EvalPart};
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

pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(path) = &args.json {
        super::check_output_path(path, "--json")?;
    }
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
