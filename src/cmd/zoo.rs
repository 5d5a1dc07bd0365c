//! `d3il zoo`: the zoo, the paper's methods trained here with the
//! reference code on demonstrations recorded from our tasks
//! (`assets/zoo/<task>/<method-slug>-s<seed>/`, docs/zoo.md). `check` reads
//! every cell and checks its files against its provenance record (what
//! `d3il serve` does at start); `reeval` evaluates every cell again with
//! this build, under the protocol and evaluator seed its result recorded,
//! and writes what moved: the version-drift record.

use crate::common::evaluation::{
    build_job, load_then_fingerprint, print_timing, progress_printer, EvalArgs,
};
use crate::common::flags::ZooArg;
use anyhow::Context;
use clap::Parser;
use d3il_protocol::EvalResult;
use d3il_server::zoo::{read_zoo, ZooCell};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(subcommand)]
    pub action: Action,
}

#[derive(clap::Subcommand, Debug)]
pub enum Action {
    /// Read every zoo cell and check its files against the sha256s its provenance.json lists, as `d3il serve` does at start.
    Check {
        #[command(flatten)]
        zoo: ZooArg,
    },
    /// Re-evaluate every zoo cell with this build (the protocol and evaluator seed its result recorded) and write a Markdown table of what moved (success, entropies: old, new, difference).
    Reeval {
        #[command(flatten)]
        zoo: ZooArg,
        /// Write the drift table here (default: standard output).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Only the cells whose name (`<task>/<dir>`) contains this text.
        #[arg(long)]
        cell: Option<String>,
        /// Rollouts simulated at once.
        #[arg(long, default_value_t = 96)]
        max_live: usize,
    },
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.action {
        Action::Check { zoo } => check(&zoo),
        Action::Reeval {
            zoo,
            out,
            cell,
            max_live,
        } => {
            if let Some(path) = &out {
                crate::common::check_output_path(path, "--out")?;
            }
            let dir = zoo.dir().context("--zoo none: no zoo to re-evaluate")?;
            let table = reeval(&dir, cell.as_deref(), max_live)?;
            match &out {
                Some(path) => {
                    std::fs::write(path, &table)
                        .with_context(|| format!("writing {}", path.display()))?;
                    eprintln!("wrote {}", path.display());
                }
                None => print!("{table}"),
            }
            Ok(())
        }
    }
}

fn check(zoo: &ZooArg) -> anyhow::Result<()> {
    let dir = zoo.dir().context("--zoo none: no zoo to check")?;
    let cells = read_zoo(&dir);
    let mut bad = 0;
    for (path, r) in &cells {
        match r {
            Ok(c) => println!(
                "ok      {}: {} seed {}, {} ({} protocol), success {:.3}",
                c.name,
                c.provenance.method,
                c.provenance.seed,
                d3il_server::zoo::data_source(&c.provenance.demos.version),
                c.result.manifest.protocol.as_str(),
                c.result.metrics.success_rate.value
            ),
            Err(e) => {
                bad += 1;
                println!("skipped {}: {e}", path.display());
            }
        }
    }
    let bytes = d3il_server::zoo::size_bytes(&dir)
        .with_context(|| format!("reading the sizes of the files under {}", dir.display()))?;
    let mb = |b: u64| b as f64 / 1e6;
    println!(
        "{} cells under {}, {bad} skipped; {:.1} MB of the zoo's size budget of {:.0} MB",
        cells.len(),
        dir.display(),
        mb(bytes),
        mb(d3il_server::zoo::SIZE_BUDGET_BYTES)
    );
    anyhow::ensure!(bad == 0, "{bad} zoo cells fail their checks");
    anyhow::ensure!(
        bytes <= d3il_server::zoo::SIZE_BUDGET_BYTES,
        "the zoo is {:.1} MB, over its size budget of {:.0} MB (docs/zoo.md, Size): \
         ship fewer or smaller cells, or state a new budget with its reason",
        mb(bytes),
        mb(d3il_server::zoo::SIZE_BUDGET_BYTES)
    );
    Ok(())
}

/// `d3il eval`'s arguments for a cell: its ONNX and manifest, on its task,
/// with the protocol and evaluator seed its result recorded.
#[derive(clap::Parser)]
struct EvalCli {
    #[command(flatten)]
    args: EvalArgs,
}

fn eval_args(c: &ZooCell, max_live: usize) -> anyhow::Result<EvalArgs> {
    let m = &c.result.manifest;
    // A result of fewer rollouts per initial state than the protocol's (a
    // sample, `d3il eval --rollouts-per-state N`) is re-made as it was made.
    let protocol_rollouts = m.task.protocol_size(m.protocol, m.n_contexts).1;
    let sample = (m.rollouts_per_context < protocol_rollouts).then(|| {
        [
            "--rollouts-per-state".to_string(),
            m.rollouts_per_context.to_string(),
        ]
    });
    let cli = EvalCli::try_parse_from(
        [
            "eval".to_string(),
            "--task".into(),
            m.task.slug().into(),
            "--policy".into(),
            c.dir.join("policy.onnx").to_string_lossy().into_owned(),
            "--manifest".into(),
            c.dir.join("policy.json").to_string_lossy().into_owned(),
            "--protocol".into(),
            m.protocol.as_str().into(),
            "--seed".into(),
            m.seed.to_string(),
            "--max-live".into(),
            max_live.to_string(),
        ]
        .into_iter()
        .chain(sample.into_iter().flatten()),
    )
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(cli.args)
}

/// Evaluates the cell again through `d3il eval`'s own entry points.
fn evaluate(c: &ZooCell, max_live: usize) -> anyhow::Result<EvalResult> {
    let args = eval_args(c, max_live)?;
    let mut job = build_job(&args)?;
    let (task, mut policy, info, opts) = load_then_fingerprint(&args, &mut job)?;
    let mut on_progress = progress_printer();
    let run = d3il_evaluator::eval::EvalRun::all().counting(&mut on_progress);
    let (r, t) = d3il_evaluator::eval::evaluate(&task, policy.as_mut(), &info, &opts, run)?;
    print_timing(&t);
    Ok(r)
}

/// One re-evaluated cell: what it recorded and what this build gives.
struct Moved {
    cell: String,
    method: String,
    recorded_fingerprint: String,
    old: [f64; 3],
    new: [f64; 3],
}

fn metrics(r: &EvalResult) -> [f64; 3] {
    let m = &r.metrics;
    [
        m.success_rate.value,
        m.behaviour_entropy.value,
        m.conditional_entropy.value,
    ]
}

fn reeval(dir: &Path, only: Option<&str>, max_live: usize) -> anyhow::Result<String> {
    let cells: Vec<_> = read_zoo(dir)
        .into_iter()
        .filter(|(p, _)| only.is_none_or(|o| p.to_string_lossy().contains(o)))
        .collect();
    anyhow::ensure!(
        !cells.is_empty(),
        "no zoo cells under {}{}",
        dir.display(),
        only.map(|o| format!(" matching `{o}`")).unwrap_or_default()
    );
    let build = crate::common::build::this_build()?;
    let mut moved = vec![];
    let mut skipped = vec![];
    for (path, cell) in cells {
        let c = match cell {
            Ok(c) => c,
            Err(e) => {
                eprintln!("skipped {}: {e}", path.display());
                skipped.push((path, e.to_string()));
                continue;
            }
        };
        eprintln!(
            "re-evaluating {} ({} protocol, seed {})",
            c.name,
            c.result.manifest.protocol.as_str(),
            c.result.manifest.seed
        );
        let new = evaluate(&c, max_live).with_context(|| format!("re-evaluating {}", c.name))?;
        moved.push(Moved {
            cell: c.name.clone(),
            method: c.provenance.method.clone(),
            recorded_fingerprint: c
                .result
                .manifest
                .build
                .as_ref()
                .and_then(|b| b.physics_fingerprint.clone())
                .unwrap_or_else(|| "not recorded".into()),
            old: metrics(&c.result),
            new: metrics(&new),
        });
    }
    Ok(drift_table(dir, &build, &moved, &skipped))
}

fn drift_table(
    dir: &Path,
    build: &d3il_protocol::BuildIdentity,
    moved: &[Moved],
    skipped: &[(PathBuf, String)],
) -> String {
    let this = build.physics_fingerprint.as_deref().unwrap_or("unknown");
    let mut out = String::from("# Zoo version drift\n\n");
    let _ = writeln!(
        out,
        "The zoo at `{}` re-evaluated by the build with physics fingerprint `{this}` (git commit `{}`, evaluator {}), \
         each cell with the protocol and evaluator seed its result recorded. Old: the shipped `result.json`; new: this \
         build; Δ = new − old. H: behaviour entropy; H(·|s0): conditional behaviour entropy.\n",
        dir.display(),
        build.git_commit,
        env!("CARGO_PKG_VERSION")
    );
    out.push_str(
        "| Cell | Method | Made by | Success old | new | Δ | H old | new | Δ | H(·\\|s0) old | new | Δ | Moved |\n",
    );
    out.push_str(
        "| :-- | :-- | :-- | --: | --: | --: | --: | --: | --: | --: | --: | --: | :-- |\n",
    );
    for m in moved {
        let mut cells = vec![
            m.cell.clone(),
            m.method.clone(),
            if m.recorded_fingerprint == this {
                format!("{} (this build)", m.recorded_fingerprint)
            } else {
                m.recorded_fingerprint.clone()
            },
        ];
        let mut any = false;
        for k in 0..3 {
            let d = m.new[k] - m.old[k];
            any |= d.abs() > 5e-4;
            cells.push(format!("{:.3}", m.old[k]));
            cells.push(format!("{:.3}", m.new[k]));
            cells.push(format!("{d:+.3}"));
        }
        cells.push(if any { "**yes**" } else { "no" }.into());
        let _ = writeln!(out, "| {} |", cells.join(" | "));
    }
    let n_moved = moved
        .iter()
        .filter(|m| (0..3).any(|k| (m.new[k] - m.old[k]).abs() > 5e-4))
        .count();
    let _ = writeln!(
        out,
        "\n{} cells re-evaluated, {n_moved} moved by more than 0.0005 on a metric.",
        moved.len()
    );
    if !skipped.is_empty() {
        out.push_str("\nSkipped (their files fail the provenance checks):\n\n");
        for (p, e) in skipped {
            let _ = writeln!(out, "- `{}`: {e}", p.display());
        }
    }
    out
}
