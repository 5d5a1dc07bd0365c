//! `d3il merge part*.json` (docs/cluster.md): joins the part files of
//! `d3il eval --shard K/N --json part.json` (eval.rs) into the result (and
//! table) of a plain `d3il eval`; those of `d3il eval --suite robustness
//! --shard K/N` into its robustness document (docs/robustness.md).

use anyhow::{bail, Context};
use d3il_evaluator::shard::{self, EvalPart};
use d3il_protocol::robustness::{RobustnessPart, ROBUSTNESS_PART_FORMAT};

/// A part file's format tag, read before the whole file.
#[derive(serde::Deserialize)]
struct FormatTag {
    format: String,
}
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
        crate::common::check_output_path(path, "--json")?;
    }
    let mut parts = Vec::with_capacity(args.parts.len());
    let mut suite_parts = Vec::new();
    for path in &args.parts {
        let text = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        // The parts of `d3il eval --suite robustness --shard K/N`.
        let format = serde_json::from_slice::<FormatTag>(&text).map(|t| t.format);
        if format.as_deref().ok() == Some(ROBUSTNESS_PART_FORMAT) {
            let part: RobustnessPart = serde_json::from_slice(&text).with_context(|| {
                format!("{} is not a valid robustness part file", path.display())
            })?;
            suite_parts.push((path.display().to_string(), part));
            continue;
        }
        let part: EvalPart = serde_json::from_slice(&text).with_context(|| {
            format!(
                "{} is not a part file of `d3il eval --shard K/N --json FILE`",
                path.display()
            )
        })?;
        parts.push((path.display().to_string(), part));
    }
    if !suite_parts.is_empty() {
        if let Some((file, _)) = parts.first() {
            bail!("{file} is a plain evaluation's part but {} is a robustness evaluation's: merge the parts of one evaluation", suite_parts[0].0);
        }
        let doc = d3il_evaluator::suite_shard::merge_suite(suite_parts)?;
        print!("{}", crate::common::text::robustness(&doc));
        if let Some(path) = &args.json {
            std::fs::write(path, serde_json::to_vec_pretty(&doc)?)
                .with_context(|| format!("writing {}", path.display()))?;
            eprintln!("wrote {}", path.display());
        }
        return Ok(());
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
