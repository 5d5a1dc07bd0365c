//! `d3il intervals`: a result or robustness document made before 0.5.0
//! brought to this version's intervals (docs/intervals.md), as the
//! server does with every stored result when it starts
//! (`d3il_metrics::recompute`), and what moved.

use anyhow::Context;
use d3il_metrics::recompute::{recompute_intervals, recompute_robustness};
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::{Estimate, EvalResult, Metrics, PairedDifference};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Result documents (`d3il eval --json`) or robustness documents (`d3il eval --suite robustness --json`), plain or gzipped (`.json.gz`).
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Write the recomputed document here (with one input file only).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print only the N largest changes (all by default).
    #[arg(long)]
    pub top: Option<usize>,
}

/// One estimate before and after.
#[derive(Debug, Clone, PartialEq)]
pub struct Change {
    pub file: String,
    pub what: String,
    pub before: String,
    pub after: String,
    /// How far the interval moved: the larger shift of its two ends; an
    /// interval given or taken away counts as its width.
    pub moved: f64,
}

fn text(e: &Estimate, p: Option<f64>) -> String {
    let p = p.map(|p| format!(", p {p:.4}")).unwrap_or_default();
    match e.interval() {
        Some((lo, hi)) => format!("{:.3} [{lo:.3}, {hi:.3}]{p}", e.value),
        None => format!("{:.3}, {}{p}", e.value, e.interval_text(3)),
    }
}

fn moved(a: &Estimate, b: &Estimate) -> f64 {
    match (a.interval(), b.interval()) {
        (Some((l0, h0)), Some((l1, h1))) => (l1 - l0).abs().max((h1 - h0).abs()),
        (Some((l, h)), None) | (None, Some((l, h))) => h - l,
        (None, None) => 0.0,
    }
}

fn push(out: &mut Vec<Change>, file: &str, what: String, a: &Estimate, b: &Estimate) {
    out.push(Change {
        file: file.into(),
        what,
        before: text(a, None),
        after: text(b, None),
        moved: moved(a, b),
    });
}

fn metrics(out: &mut Vec<Change>, file: &str, prefix: &str, a: &Metrics, b: &Metrics) {
    for (name, x, y) in [
        ("success rate", &a.success_rate, &b.success_rate),
        (
            "behaviour entropy",
            &a.behaviour_entropy,
            &b.behaviour_entropy,
        ),
        (
            "conditional entropy",
            &a.conditional_entropy,
            &b.conditional_entropy,
        ),
    ] {
        push(out, file, format!("{prefix}{name}"), x, y);
    }
    if let (Some(la), Some(lb)) = (&a.stacking_levels, &b.stacking_levels) {
        for (i, (x, y)) in la.iter().zip(lb).take(2).enumerate() {
            push(
                out,
                file,
                format!("{prefix}stacking-{} success rate", i + 1),
                &x.success_rate,
                &y.success_rate,
            );
        }
    }
}

fn paired(
    out: &mut Vec<Change>,
    file: &str,
    what: String,
    a: &PairedDifference,
    b: &PairedDifference,
) {
    out.push(Change {
        file: file.into(),
        what,
        before: text(&a.difference, Some(a.p_value)),
        after: text(&b.difference, Some(b.p_value)),
        moved: moved(&a.difference, &b.difference),
    });
}

/// The document at `path` recomputed (JSON text) and what moved.
pub fn recompute_file(path: &Path) -> anyhow::Result<(String, Vec<Change>)> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .with_context(|| format!("{}: not a file name", path.display()))?;
    let bytes = d3il_server::zoo::read_document(dir, name.trim_end_matches(".gz"))
        .with_context(|| format!("cannot read {}", path.display()))?;
    let value: serde_json::Value = serde_json::from_slice(&bytes)
        .with_context(|| format!("{} is not JSON", path.display()))?;
    let file = path.display().to_string();
    let mut changes = Vec::new();
    let text = if value.get("control").is_some() && value.get("levels").is_some() {
        let old: RobustnessResult = serde_json::from_value(value).with_context(|| {
            format!("{file} looks like a robustness document but does not parse as one")
        })?;
        let mut new = old.clone();
        recompute_robustness(&mut new).with_context(|| format!("{file}: cannot recompute"))?;
        metrics(
            &mut changes,
            &file,
            "level 0 ",
            &old.control.metrics,
            &new.control.metrics,
        );
        for (a, b) in old.levels.iter().zip(&new.levels) {
            let level = format!("{} {} ({})", a.axis, a.level, a.setting.label);
            push(
                &mut changes,
                &file,
                format!("{level} success rate"),
                &a.result.metrics.success_rate,
                &b.result.metrics.success_rate,
            );
            paired(
                &mut changes,
                &file,
                format!("{level} drop"),
                &a.paired.success_rate,
                &b.paired.success_rate,
            );
        }
        serde_json::to_string(&new)?
    } else {
        let old: EvalResult = serde_json::from_value(value).with_context(|| {
            format!("{file} is neither a result document (`d3il eval --json`) nor a robustness document")
        })?;
        let mut new = old.clone();
        recompute_intervals(&mut new).with_context(|| format!("{file}: cannot recompute"))?;
        metrics(&mut changes, &file, "", &old.metrics, &new.metrics);
        serde_json::to_string(&new)?
    };
    Ok((text, changes))
}

/// The changes as a Markdown table, largest first.
pub fn table(changes: &[Change]) -> String {
    let mut s = String::from(
        "| document | estimate | stored | this build | moved |\n|---|---|---|---|---|\n",
    );
    for c in changes {
        s += &format!(
            "| {} | {} | {} | {} | {:.3} |\n",
            c.file, c.what, c.before, c.after, c.moved
        );
    }
    s
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.out.is_some() && args.files.len() != 1 {
        anyhow::bail!(
            "--out writes one recomputed document; give one input file (got {})",
            args.files.len()
        );
    }
    let mut all = Vec::new();
    for f in &args.files {
        let (text, changes) = recompute_file(f)?;
        if let Some(out) = &args.out {
            std::fs::write(out, text).with_context(|| format!("cannot write {}", out.display()))?;
        }
        all.extend(changes);
    }
    all.sort_by(|a, b| b.moved.total_cmp(&a.moved));
    if let Some(n) = args.top {
        all.truncate(n);
    }
    print!("{}", table(&all));
    Ok(())
}
