//! The robustness track's tables (docs/robustness.md): methods ×
//! axes with retained-success scores and their intervals, grouped by suite
//! version. `d3il tables --table robustness` prints them (LaTeX, Markdown,
//! CSV) and the leaderboard's Robustness view shows the same groups with the
//! figures of [`figures`]. Rows of different suite files (name and sha256)
//! or protocols are never ranked together. Within a group a method's
//! training seeds are aggregated as the ordinary boards aggregate them
//! ([`d3il_metrics::aggregate_seeds`]: mean and sample standard deviation,
//! [`SuiteGroup::methods`]); the rows per seed follow.

pub mod figures;

use crate::numfmt::{latex_escape, markdown_escape, mean_std, three_decimals};
use crate::{Format, TablesError};
use d3il_protocol::perturbation::Axis;
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::{Estimate, ProtocolKind, Stat, TaskId};
use std::fmt::Write;

/// One evaluated submission's robustness (its document without rollout
/// records is enough).
#[derive(Debug, Clone)]
pub struct RobustnessEntry {
    pub submission_id: i64,
    pub method: String,
    pub training_seed: i64,
    pub protocol: ProtocolKind,
    pub doc: RobustnessResult,
}

impl RobustnessEntry {
    /// The row's label: the method and its training seed.
    pub fn label(&self) -> String {
        format!("{} (seed {})", self.method, self.training_seed)
    }

    /// The score of `axis`, if the suite has it and level 0 had a success.
    pub fn axis_score(&self, axis: Axis) -> Option<Estimate> {
        self.doc
            .axes
            .iter()
            .find(|a| a.axis == axis)
            .and_then(|a| a.score)
    }

    /// The label of the row's score intervals when their measured coverage
    /// is below the nominal 95 % (too few initial states), else empty.
    pub fn score_coverage_text(&self) -> String {
        self.doc
            .score_coverage()
            .map(|c| c.label)
            .unwrap_or_default()
    }

    /// Success rate (with interval) per level of `axis`, level 0 first.
    pub fn curve(&self, axis: Axis) -> Vec<(usize, Estimate)> {
        let mut c = vec![(0, self.doc.control.metrics.success_rate)];
        c.extend(
            self.doc
                .levels
                .iter()
                .filter(|l| l.axis == axis)
                .map(|l| (l.level, l.result.metrics.success_rate)),
        );
        c
    }
}

/// The entries of one task evaluated with one suite file under one
/// protocol: the only rows ranked together.
#[derive(Debug, Clone)]
pub struct SuiteGroup<'a> {
    pub task: TaskId,
    pub suite: String,
    pub suite_sha256: String,
    pub protocol: ProtocolKind,
    /// Rollouts per initial state the documents ran (`d3il eval
    /// --rollouts-per-state`): a sampled protocol is a group of its own.
    pub rollouts_per_state: usize,
    /// The suite's axes in its order.
    pub axes: Vec<Axis>,
    /// Ranked: overall score, highest first (rows without one last).
    pub entries: Vec<&'a RobustnessEntry>,
}

impl SuiteGroup<'_> {
    pub fn title(&self) -> String {
        format!(
            "{}: suite {} (sha256 {}…), {} protocol{}",
            self.task.title(),
            self.suite,
            &self.suite_sha256[..self.suite_sha256.len().min(12)],
            self.protocol.as_str(),
            if self.protocol == ProtocolKind::Quick {
                " (smoke test: 3 initial states × 2 rollouts per level)".to_string()
            } else if self.rollouts_per_state < self.task.paper_protocol().rollouts {
                format!(
                    " sampled: its initial states, {} rollout{} of each per level (of {})",
                    self.rollouts_per_state,
                    if self.rollouts_per_state == 1 {
                        ""
                    } else {
                        "s"
                    },
                    self.task.paper_protocol().rollouts
                )
            } else {
                String::new()
            }
        )
    }

    /// `(level, label)` of every level of `axis` (level 0 is the control),
    /// from the first entry (every entry of a group has the same suite file).
    pub fn levels(&self, axis: Axis) -> Vec<(usize, String)> {
        let mut v = vec![(0, "control".to_string())];
        if let Some(e) = self.entries.first() {
            v.extend(
                e.doc
                    .levels
                    .iter()
                    .filter(|l| l.axis == axis)
                    .map(|l| (l.level, l.setting.label.clone())),
            );
        }
        v
    }
}

/// A statistic over a method's seeds: the aggregate and how many seeds had
/// a value (a seed without success at level 0 has no scores).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeedStat {
    pub stat: Stat,
    pub n: usize,
}

/// One method of a suite group over its training seeds.
#[derive(Debug, Clone)]
pub struct MethodRow<'a> {
    pub method: String,
    /// Its entries (one per submission: seed), in the group's ranking.
    pub seeds: Vec<&'a RobustnessEntry>,
    pub control: SeedStat,
    pub entropy: SeedStat,
    /// Per axis of the group, in its order.
    pub axes: Vec<Option<SeedStat>>,
    pub overall: Option<SeedStat>,
}

impl MethodRow<'_> {
    /// The training seeds, ascending.
    pub fn seed_list(&self) -> String {
        let mut s: Vec<i64> = self.seeds.iter().map(|e| e.training_seed).collect();
        s.sort_unstable();
        s.iter()
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Aggregates `values` over seeds (`None` entries: seeds without a value).
fn seed_stat(values: impl Iterator<Item = Option<f64>>) -> Option<SeedStat> {
    let v: Vec<f64> = values.flatten().collect();
    let stat = d3il_metrics::aggregate_seeds(&v).ok()?;
    Some(SeedStat { stat, n: v.len() })
}

/// `mean ± std` over the seeds (the boards' format), with `(n of N seeds)`
/// when only some seeds have a value; `–` when none has.
pub fn seed_text(s: &Option<SeedStat>, seeds: usize) -> String {
    match s {
        Some(s) => {
            let t = mean_std(s.stat.mean, s.stat.std, s.n);
            if s.n < seeds {
                format!("{t} ({} of {seeds} seeds)", s.n)
            } else {
                t
            }
        }
        None => "–".into(),
    }
}

impl<'a> SuiteGroup<'a> {
    /// The group's methods, each over its seeds, ranked by mean overall
    /// score (highest first; methods without one last, then by name).
    pub fn methods(&self) -> Vec<MethodRow<'a>> {
        let mut names: Vec<&str> = vec![];
        for e in &self.entries {
            if !names.contains(&e.method.as_str()) {
                names.push(&e.method);
            }
        }
        let mut rows: Vec<MethodRow<'a>> = names
            .into_iter()
            .map(|name| {
                let seeds: Vec<&'a RobustnessEntry> = self
                    .entries
                    .iter()
                    .copied()
                    .filter(|e| e.method == name)
                    .collect();
                let m = |f: &dyn Fn(&RobustnessEntry) -> Option<f64>| {
                    seed_stat(seeds.iter().map(|e| f(e)))
                };
                MethodRow {
                    method: name.to_string(),
                    control: m(&|e| Some(e.doc.control.metrics.success_rate.value))
                        .expect("a method has a seed"),
                    entropy: m(&|e| Some(e.doc.control.metrics.conditional_entropy.value))
                        .expect("a method has a seed"),
                    axes: self
                        .axes
                        .iter()
                        .map(|&a| m(&|e| e.axis_score(a).map(|s| s.value)))
                        .collect(),
                    overall: m(&|e| e.doc.overall.map(|o| o.value)),
                    seeds,
                }
            })
            .collect();
        rows.sort_by(|a, b| {
            let v = |r: &MethodRow<'_>| r.overall.map(|o| o.stat.mean);
            match (v(a), v(b)) {
                (Some(x), Some(y)) => y.total_cmp(&x),
                (Some(_), None) => std::cmp::Ordering::Less,
                (None, Some(_)) => std::cmp::Ordering::Greater,
                (None, None) => std::cmp::Ordering::Equal,
            }
            .then(a.method.cmp(&b.method))
        });
        rows
    }
}

/// Groups entries by (task, suite file, sha256, protocol): paper protocol
/// before quick, newer suite files first; within a group ranked by overall
/// score.
pub fn group_by_suite(entries: &[RobustnessEntry]) -> Vec<SuiteGroup<'_>> {
    let mut groups: Vec<SuiteGroup<'_>> = Vec::new();
    for e in entries {
        let key = |g: &SuiteGroup<'_>| {
            g.task == e.doc.task
                && g.suite == e.doc.suite
                && g.suite_sha256 == e.doc.suite_sha256
                && g.protocol == e.protocol
                && g.rollouts_per_state == e.doc.control.manifest.rollouts_per_context
        };
        match groups.iter_mut().find(|g| key(g)) {
            Some(g) => g.entries.push(e),
            None => groups.push(SuiteGroup {
                task: e.doc.task,
                suite: e.doc.suite.clone(),
                suite_sha256: e.doc.suite_sha256.clone(),
                protocol: e.protocol,
                rollouts_per_state: e.doc.control.manifest.rollouts_per_context,
                axes: e.doc.axes.iter().map(|a| a.axis).collect(),
                entries: vec![e],
            }),
        }
    }
    for g in &mut groups {
        g.entries.sort_by(|a, b| {
            let v = |e: &RobustnessEntry| e.doc.overall.map(|o| o.value);
            match (v(a), v(b)) {
                (Some(x), Some(y)) => y.total_cmp(&x),
                (Some(_), None) => std::cmp::Ordering::Less,
                (None, Some(_)) => std::cmp::Ordering::Greater,
                (None, None) => std::cmp::Ordering::Equal,
            }
            .then(a.submission_id.cmp(&b.submission_id))
        });
    }
    groups.sort_by(|a, b| {
        (a.task, a.protocol != ProtocolKind::Paper)
            .cmp(&(b.task, b.protocol != ProtocolKind::Paper))
            .then(b.suite.cmp(&a.suite))
            .then(a.suite_sha256.cmp(&b.suite_sha256))
            .then(b.rollouts_per_state.cmp(&a.rollouts_per_state))
    });
    groups
}

/// `value [low, high]`, `value (no interval (3 states))` when the estimate
/// has no interval, or `–` when there is no estimate.
pub fn interval_text(e: &Option<Estimate>) -> String {
    match e {
        Some(e) => match e.interval() {
            Some((lo, hi)) => format!(
                "{} [{}, {}]",
                three_decimals(e.value),
                three_decimals(lo),
                three_decimals(hi)
            ),
            None => format!("{} ({})", three_decimals(e.value), e.interval_text(3)),
        },
        None => "–".into(),
    }
}

/// An interval's ends as CSV cells: empty when there is none.
fn ci_cells(e: &Estimate) -> [String; 2] {
    match e.interval() {
        Some((lo, hi)) => [format!("{lo}"), format!("{hi}")],
        None => [String::new(), String::new()],
    }
}

/// What the scores mean (every format prints it); the scores' measured
/// coverage and which rows carry a label come from
/// [`d3il_protocol::interval::score_coverage_note`].
pub fn note() -> String {
    format!(
        "Score: success retained (a level's success rate over level 0's), averaged over an axis's levels; overall: the mean of the axes' scores; scores carry 95 % paired bootstrap intervals over initial states (bias-corrected percentile, for the score's expected value at this size; {}: the per-seed rows' \"{SCORE_COVERAGE_COLUMN}\", docs/intervals.md); success rates and drops the intervals of docs/intervals.md (none with fewer than 5 initial states, and the reason instead). Methods: mean ± sample standard deviation over training seeds, as on the boards; the rows per seed (with intervals) follow. Level 0 is the plain evaluation (the control arm); every level runs on the same initial states, seed and rollout ids. Rows of different suite files or protocols are never ranked together. – : no success at level 0 (nothing to retain).",
        d3il_protocol::interval::score_coverage_note()
    )
}

/// The per-seed tables' last column: the row's score-interval label
/// ([`RobustnessEntry::score_coverage_text`]).
pub const SCORE_COVERAGE_COLUMN: &str = "Score intervals' coverage";

fn header(g: &SuiteGroup<'_>) -> Vec<String> {
    let mut h = vec![
        "Rank".to_string(),
        "Method".into(),
        "Level 0 success".into(),
        "H|s0".into(),
    ];
    h.extend(g.axes.iter().map(|a| a.to_string()));
    h.push("Overall".into());
    h
}

/// [`header`] with the number of seeds after the method.
fn method_header(g: &SuiteGroup<'_>) -> Vec<String> {
    let mut h = header(g);
    h.insert(2, "Seeds".into());
    h
}

/// [`header`] of the rows per seed: their intervals' label last.
fn seed_header(g: &SuiteGroup<'_>) -> Vec<String> {
    let mut h = header(g);
    h.push(SCORE_COVERAGE_COLUMN.into());
    h
}

fn method_cells(rank: usize, r: &MethodRow<'_>) -> Vec<String> {
    let n = r.seeds.len();
    let mut c = vec![
        rank.to_string(),
        r.method.clone(),
        r.seed_list(),
        seed_text(&Some(r.control), n),
        seed_text(&Some(r.entropy), n),
    ];
    c.extend(r.axes.iter().map(|a| seed_text(a, n)));
    c.push(seed_text(&r.overall, n));
    c
}

fn cells(rank: usize, e: &RobustnessEntry, g: &SuiteGroup<'_>) -> Vec<String> {
    let m = &e.doc.control.metrics;
    let mut c = vec![
        rank.to_string(),
        e.label(),
        interval_text(&Some(m.success_rate)),
        three_decimals(m.conditional_entropy.value),
    ];
    c.extend(g.axes.iter().map(|&a| interval_text(&e.axis_score(a))));
    c.push(interval_text(&e.doc.overall));
    c.push(e.score_coverage_text());
    c
}

/// The robustness table of `entries` in `format`.
pub fn render_robustness(
    entries: &[RobustnessEntry],
    format: Format,
) -> Result<String, TablesError> {
    let groups = group_by_suite(entries);
    if groups.is_empty() {
        return Err(TablesError::NoFigureData {
            figure: "robustness table",
            hint: "no submission evaluated with suite=robustness is in the database (submit with `d3il submit --suite robustness`)",
        });
    }
    Ok(match format {
        Format::Markdown => markdown(&groups),
        Format::Latex => latex(&groups),
        Format::Csv => csv(&groups)?,
    })
}

fn markdown(groups: &[SuiteGroup<'_>]) -> String {
    let mut out = format!("**D3IL robustness.** {}\n", markdown_escape(&note()));
    for g in groups {
        let _ = writeln!(out, "\n**{}**\n", markdown_escape(&g.title()));
        let methods: Vec<Vec<String>> = g
            .methods()
            .iter()
            .enumerate()
            .map(|(i, r)| method_cells(i + 1, r))
            .collect();
        markdown_table(&mut out, &method_header(g), &methods);
        let _ = writeln!(out, "\nPer seed:\n");
        let seeds: Vec<Vec<String>> = g
            .entries
            .iter()
            .enumerate()
            .map(|(i, e)| cells(i + 1, e, g))
            .collect();
        markdown_table(&mut out, &seed_header(g), &seeds);
    }
    out
}

fn markdown_table(out: &mut String, h: &[String], rows: &[Vec<String>]) {
    let _ = writeln!(
        out,
        "| {} |",
        h.iter()
            .map(|s| markdown_escape(s))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    let align: Vec<&str> = (0..h.len())
        .map(|i| if i == 1 { ":--" } else { "--:" })
        .collect();
    let _ = writeln!(out, "| {} |", align.join(" | "));
    for row in rows {
        let c: Vec<String> = row.iter().map(|s| markdown_escape(s)).collect();
        let _ = writeln!(out, "| {} |", c.join(" | "));
    }
}

fn latex(groups: &[SuiteGroup<'_>]) -> String {
    let mut out = String::new();
    for g in groups {
        let methods: Vec<Vec<String>> = g
            .methods()
            .iter()
            .enumerate()
            .map(|(i, r)| method_cells(i + 1, r))
            .collect();
        latex_table(
            &mut out,
            &format!("D3IL robustness, {}. {}", g.title(), note()),
            &method_header(g),
            &methods,
        );
        let seeds: Vec<Vec<String>> = g
            .entries
            .iter()
            .enumerate()
            .map(|(i, e)| cells(i + 1, e, g))
            .collect();
        latex_table(
            &mut out,
            &format!("D3IL robustness per training seed, {}.", g.title()),
            &seed_header(g),
            &seeds,
        );
    }
    out
}

fn latex_table(out: &mut String, caption: &str, h: &[String], rows: &[Vec<String>]) {
    let _ = writeln!(out, "\\begin{{table}}[t]\n\\centering\\small");
    let _ = writeln!(out, "\\caption{{{}}}", latex_escape(caption));
    let _ = writeln!(out, "\\begin{{tabular}}{{rl{}}}", "r".repeat(h.len() - 2));
    let _ = writeln!(out, "\\toprule");
    let _ = writeln!(
        out,
        "{} \\\\",
        h.iter()
            .map(|s| latex_escape(s))
            .collect::<Vec<_>>()
            .join(" & ")
    );
    let _ = writeln!(out, "\\midrule");
    for row in rows {
        let c: Vec<String> = row.iter().map(|s| latex_escape(s)).collect();
        let _ = writeln!(out, "{} \\\\", c.join(" & "));
    }
    let _ = writeln!(out, "\\bottomrule\n\\end{{tabular}}\n\\end{{table}}\n");
}

const CSV_HEADER: [&str; 22] = [
    "task",
    "suite",
    "suite_sha256",
    "protocol",
    "rank",
    "method",
    "training_seed",
    "submission_id",
    "axis",
    "level",
    "setting",
    "success_rate",
    "success_ci_low",
    "success_ci_high",
    "drop",
    "drop_ci_low",
    "drop_ci_high",
    "p_value",
    "retained",
    "seeds_std",
    "n_seeds",
    "score_coverage",
];

/// One line per level of every axis (level 0 once, axis `control`), then a
/// line per axis score (level `score`) and the overall score (axis
/// `overall`): the score lines carry the score in `retained` and its
/// interval in the success interval columns. Then per method the lines over
/// its seeds (`training_seed` `all`, level `seeds`): level 0's success rate
/// and the scores as the mean in `success_rate` (control) or
/// `retained` (scores), the sample standard deviation in `seeds_std` and the
/// number of seeds with a value in `n_seeds`. A submission's score lines
/// carry in `score_coverage` the label of intervals whose measured coverage
/// is below the nominal 95 % (empty otherwise, and on every other line).
fn csv(groups: &[SuiteGroup<'_>]) -> Result<String, TablesError> {
    let f = |x: f64| format!("{x}");
    let mut rows: Vec<Vec<String>> = Vec::new();
    for g in groups {
        for (i, m) in g.methods().iter().enumerate() {
            let mut lines = vec![("control".to_string(), Some(m.control))];
            lines.extend(g.axes.iter().zip(&m.axes).map(|(a, s)| (a.to_string(), *s)));
            lines.push(("overall".into(), m.overall));
            for (axis, stat) in lines {
                let control = axis == "control";
                let (mean, std, n) = match stat {
                    Some(s) => (f(s.stat.mean), f(s.stat.std), s.n.to_string()),
                    None => (String::new(), String::new(), "0".into()),
                };
                rows.push(vec![
                    g.task.slug().to_string(),
                    g.suite.clone(),
                    g.suite_sha256.clone(),
                    g.protocol.as_str().to_string(),
                    (i + 1).to_string(),
                    m.method.clone(),
                    "all".into(),
                    String::new(),
                    axis,
                    "seeds".into(),
                    format!("mean over {} seeds", m.seeds.len()),
                    if control { mean.clone() } else { String::new() },
                    String::new(),
                    String::new(),
                    String::new(),
                    String::new(),
                    String::new(),
                    String::new(),
                    if control { String::new() } else { mean },
                    std,
                    n,
                    String::new(),
                ]);
            }
        }
        for (i, e) in g.entries.iter().enumerate() {
            let base = vec![
                g.task.slug().to_string(),
                g.suite.clone(),
                g.suite_sha256.clone(),
                g.protocol.as_str().to_string(),
                (i + 1).to_string(),
                e.method.clone(),
                e.training_seed.to_string(),
                e.submission_id.to_string(),
            ];
            let s0 = e.doc.control.metrics.success_rate;
            let mut r = base.clone();
            r.extend([
                "control".into(),
                "0".into(),
                "standard protocol".into(),
                f(s0.value),
                ci_cells(&s0)[0].clone(),
                ci_cells(&s0)[1].clone(),
                String::new(),
                String::new(),
                String::new(),
                String::new(),
                "1".into(),
            ]);
            r.extend([String::new(), String::new(), String::new()]);
            rows.push(r);
            for l in &e.doc.levels {
                let s = l.result.metrics.success_rate;
                let d = &l.paired.success_rate;
                let mut r = base.clone();
                r.extend([
                    l.axis.to_string(),
                    l.level.to_string(),
                    l.setting.label.clone(),
                    f(s.value),
                    ci_cells(&s)[0].clone(),
                    ci_cells(&s)[1].clone(),
                    f(d.difference.value),
                    ci_cells(&d.difference)[0].clone(),
                    ci_cells(&d.difference)[1].clone(),
                    f(d.p_value),
                    l.retained.map(f).unwrap_or_default(),
                ]);
                r.extend([String::new(), String::new(), String::new()]);
                rows.push(r);
            }
            let scores = g
                .axes
                .iter()
                .map(|&a| (a.to_string(), "score", e.axis_score(a)))
                .chain([("overall".to_string(), "score", e.doc.overall)]);
            for (axis, level, score) in scores {
                let mut r = base.clone();
                let label = if score.is_some() {
                    e.score_coverage_text()
                } else {
                    String::new()
                };
                let (v, lo, hi) = match score {
                    Some(s) => {
                        let [lo, hi] = ci_cells(&s);
                        (f(s.value), lo, hi)
                    }
                    None => Default::default(),
                };
                r.extend([
                    axis,
                    level.into(),
                    String::new(),
                    String::new(),
                    lo,
                    hi,
                    String::new(),
                    String::new(),
                    String::new(),
                    String::new(),
                    v,
                ]);
                r.extend([String::new(), String::new(), label]);
                rows.push(r);
            }
        }
    }
    crate::csv::write_csv(&CSV_HEADER, rows)
}
