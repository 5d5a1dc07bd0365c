//! The format-independent table: which groups (task columns) and rows (methods)
//! a table has, their values and which of them are bold. The LaTeX, Markdown
//! and CSV renderers only print this model, so all formats carry the same
//! numbers.

use crate::numfmt;
use crate::{MethodInfo, SourceFilter, TableKind, TablesError};
use d3il_protocol::paper::{self, PaperResults, PAPER_METHOD_ORDER};
use d3il_protocol::{ObsType, ResultCell, Source};
use std::collections::{BTreeMap, BTreeSet};

/// Tasks per block, as in the paper's tables.
const GROUPS_PER_BLOCK: usize = 3;

/// The paper's column layout of the main tables (Tables 2 and 3): three tasks
/// per block. Tasks outside this layout (evaluated only) get extra blocks.
const MAIN_STATE_LAYOUT: [[&str; 3]; 3] = [
    ["Avoiding (T1)", "Aligning (T2)", "Pushing (T3)"],
    ["Sorting-2 (T4)", "Sorting-4 (T4)", "Sorting-6 (T4)"],
    ["Stacking-1 (T5)", "Stacking-2 (T5)", "Stacking-3 (T5)"],
];
const MAIN_IMAGE_LAYOUT: [[&str; 3]; 2] = [
    ["Aligning (T2)", "Sorting-4 (T4)", "Sorting-6 (T4)"],
    ["Stacking-1 (T5)", "Stacking-2 (T5)", "Stacking-3 (T5)"],
];

/// Tasks of the preliminary table; evaluated Inserting results are stored as
/// `main` cells (see `ResultCell::table`) and are shown here too.
const PRELIM_TASKS: [&str; 2] = ["Inserting (T6)", "Arranging (T7)"];

/// Arranging sub-task columns in the order the paper printed them; the JSON
/// object order cannot be relied on (serde_json may sort keys).
const ARRANGING_SUBTASK_ORDER: [&str; 3] = ["banana", "plate", "cup"];

/// One printed column of a group.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub enum Metric {
    SuccessRate,
    /// Conditional behaviour entropy (the paper's "Entropy").
    Entropy,
    /// Success rate of one Arranging sub-task (prelim table, reported only).
    Subtask(String),
}

impl Metric {
    /// Column name in CSV output.
    pub fn csv_name(&self) -> String {
        match self {
            Metric::SuccessRate => "success_rate".to_string(),
            Metric::Entropy => "entropy".to_string(),
            Metric::Subtask(s) => format!("success_{s}"),
        }
    }

    /// Human header (plain text).
    pub fn title(&self) -> String {
        match self {
            Metric::SuccessRate => "Success Rate".to_string(),
            Metric::Entropy => "Entropy".to_string(),
            Metric::Subtask(s) => {
                let mut c = s.chars();
                match c.next() {
                    Some(f) => f.to_uppercase().chain(c).collect(),
                    None => String::new(),
                }
            }
        }
    }
}

/// A task (at one data fraction) with its metric columns.
#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    pub task: String,
    /// Shown in the datasize table's headers; 1.0 elsewhere.
    pub data_fraction: f64,
    pub metrics: Vec<Metric>,
}

/// One printed `mean ± std`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Value {
    pub mean: f64,
    pub std: f64,
    pub n_seeds: usize,
    pub bold: bool,
    /// Decides the printed precision (see the crate docs).
    pub source: Source,
}

impl Value {
    pub fn mean_text(&self) -> String {
        numfmt::number(self.mean, self.source)
    }
    /// Whether `± std` is printed: reported values as the paper printed
    /// them; evaluated values only over two or more seeds (one seed has no
    /// spread to show).
    pub fn shows_spread(&self) -> bool {
        self.source == Source::Reported || self.n_seeds >= 2
    }
    pub fn std_text(&self) -> String {
        numfmt::number(self.std, self.source)
    }
}

/// One method row of a block.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub method: String,
    pub source: Source,
    /// `velocity`/`position` in the posvel table.
    pub control: Option<String>,
    /// Evaluated rows: which initial states they used ("the original D3IL
    /// test contexts" or "our sample").
    pub initial_states: Option<String>,
    /// Evaluated image rows not drawn as the original draws them: the robot
    /// look's badge (`primitive robot`, `robot look not recorded`).
    pub robot_look: Option<String>,
    /// Evaluated rows of another build than the one making the table: why
    /// (`other build: physics fingerprint …`).
    pub build: Option<String>,
    pub info: MethodInfo,
    /// One of the paper's eleven baselines.
    pub in_paper: bool,
    /// `values[g][m]`: group `g`, metric `m` of the block; None prints `--`.
    pub values: Vec<Vec<Option<Value>>>,
}

impl Row {
    /// Rows are separated by a rule where this changes: the paper's
    /// history-free methods, its history-based methods, then methods that are
    /// not in the paper.
    pub fn section(&self) -> u8 {
        match (self.in_paper, self.info.history_based()) {
            (true, false) => 0,
            (true, true) => 1,
            (false, _) => 2,
        }
    }

    pub fn dagger(&self) -> bool {
        self.info.action_chunking
    }

    pub fn ddagger(&self) -> bool {
        self.info.history_based()
    }

    /// Parenthesised annotations after the method name: the control mode and,
    /// when both sources are shown, `eval.` for our own evaluations.
    pub fn annotations(&self, annotate_source: bool) -> Vec<String> {
        let mut a = Vec::new();
        if let Some(c) = &self.control {
            a.push(c.clone());
        }
        if annotate_source && self.source == Source::Evaluated {
            a.push("eval.".to_string());
        }
        if let Some(s) = &self.initial_states {
            a.push(s.clone());
        }
        if let Some(l) = &self.robot_look {
            a.push(l.clone());
        }
        if let Some(b) = &self.build {
            a.push(b.clone());
        }
        a
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    pub groups: Vec<Group>,
    pub rows: Vec<Row>,
}

/// What the caption states, collected from the rows shown.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CaptionFacts {
    pub tasks: Vec<String>,
    pub reported_seeds: BTreeSet<usize>,
    pub evaluated_seeds: BTreeSet<usize>,
    pub any_dagger: bool,
    pub any_ddagger: bool,
    pub any_bold: bool,
    pub paper_protocol: serde_json::Value,
}

#[derive(Debug, Clone, PartialEq)]
pub struct TableModel {
    pub kind: TableKind,
    pub obs: ObsType,
    pub source: SourceFilter,
    pub blocks: Vec<Block>,
    pub facts: CaptionFacts,
}

impl TableModel {
    /// Evaluated rows are labelled `(eval.)` only when both sources are shown.
    pub fn annotate_source(&self) -> bool {
        self.source == SourceFilter::Both
    }

    /// Widest block, in value columns.
    pub fn max_value_columns(&self) -> usize {
        self.blocks
            .iter()
            .map(|b| b.groups.iter().map(|g| g.metrics.len()).sum::<usize>())
            .max()
            .unwrap_or(0)
    }

    /// LaTeX label, e.g. `tab:d3il-main-state`.
    pub fn label(&self) -> String {
        format!("tab:d3il-{}-{}", self.kind, self.obs)
    }
}

/// One table row: evaluated rows on different initial-state sets, image rows
/// drawn with different robot looks, or rows of another build are separate
/// rows, never merged.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct RowKey {
    method: String,
    source: Source,
    control: Option<String>,
    initial_states: Option<String>,
    robot_look: Option<String>,
    build: Option<String>,
}

impl RowKey {
    fn of(c: &ResultCell) -> RowKey {
        RowKey {
            method: c.method.clone(),
            source: c.source,
            control: c.control.clone(),
            initial_states: c.initial_states.clone(),
            robot_look: c.robot_look.clone(),
            build: c.build.clone(),
        }
    }
}

/// Task order: by the paper's task number (T1..T7), then by title
/// (`Sorting-2` < `Sorting-4` < `Sorting-6`, `Stacking-1` < ...).
pub(crate) fn task_sort_key(task: &str) -> (u32, String) {
    (task_number(task).unwrap_or(u32::MAX), task.to_string())
}

/// `Sorting-4 (T4)` -> 4.
pub(crate) fn task_number(task: &str) -> Option<u32> {
    let start = task.rfind("(T")? + 2;
    let rest = &task[start..];
    let end = rest.find(')')?;
    rest[..end].parse().ok()
}

fn fraction_key(f: f64) -> i64 {
    (f * 1e6).round() as i64
}

fn selects(kind: TableKind, c: &ResultCell) -> bool {
    match kind {
        TableKind::Main | TableKind::Datasize | TableKind::Posvel => c.table == kind.as_str(),
        TableKind::Prelim => {
            c.table == "prelim"
                || (c.source == Source::Evaluated
                    && c.table == "main"
                    && PRELIM_TASKS.contains(&c.task.as_str()))
        }
    }
}

fn no_cells_hint(source: SourceFilter) -> &'static str {
    match source {
        SourceFilter::Evaluated => {
            "no submission has been evaluated for it yet: evaluate one, or use --source reported"
        }
        _ => "the paper reports this table only for state observations: try --obs state",
    }
}

/// Builds the table model from result cells. See [`crate::render_table_with`].
pub fn build_table(
    cells: &[ResultCell],
    kind: TableKind,
    obs: ObsType,
    source: SourceFilter,
    methods: &BTreeMap<String, MethodInfo>,
) -> Result<TableModel, TablesError> {
    let paper = paper::load_embedded();
    let paper_info = crate::paper_method_info();

    let admitted = |c: &&ResultCell| c.obs == obs && source.admits(c.source);
    let mut selected: Vec<&ResultCell> = cells
        .iter()
        .filter(admitted)
        .filter(|c| selects(kind, c))
        .collect();
    if kind == TableKind::Datasize {
        // Evaluated runs on all the data are stored as `main` cells: they are
        // the 100 % point of a method's data-size curve.
        let curves: BTreeSet<(&str, &str)> = selected
            .iter()
            .filter(|c| c.source == Source::Evaluated)
            .map(|c| (c.method.as_str(), c.task.as_str()))
            .collect();
        selected.extend(cells.iter().filter(admitted).filter(|c| {
            c.source == Source::Evaluated
                && c.table == "main"
                && curves.contains(&(c.method.as_str(), c.task.as_str()))
        }));
    }
    if selected.is_empty() {
        return Err(TablesError::NoCells {
            table: kind,
            obs,
            filter: source,
            hint: no_cells_hint(source),
        });
    }
    for c in &selected {
        for (what, v) in [
            ("success-rate mean", c.success_rate.mean),
            ("success-rate std", c.success_rate.std),
            ("entropy mean", c.entropy.mean),
            ("entropy std", c.entropy.std),
        ] {
            if !v.is_finite() {
                return Err(TablesError::NonFinite {
                    method: c.method.clone(),
                    task: c.task.clone(),
                    what,
                    value: v,
                });
            }
        }
    }

    // Index the cells by row and column; only the datasize table has more
    // than one data fraction per task.
    let per_fraction = kind == TableKind::Datasize;
    let mut index: BTreeMap<(RowKey, String, Option<i64>), &ResultCell> = BTreeMap::new();
    for c in &selected {
        let row = RowKey::of(c);
        let frac = per_fraction.then(|| fraction_key(c.data_fraction));
        if index.insert((row, c.task.clone(), frac), c).is_some() {
            return Err(TablesError::DuplicateCell {
                method: c.method.clone(),
                origin: c.source,
                task: c.task.clone(),
                obs: c.obs,
                data_fraction: c.data_fraction,
                control: c.control.clone().unwrap_or_else(|| "none".to_string()),
            });
        }
    }

    let subtasks = paper_subtasks(&paper);
    let layout = block_layout(kind, obs, &selected);
    let blocks_groups: Vec<Vec<Group>> = layout
        .into_iter()
        .map(|groups| {
            groups
                .into_iter()
                .map(|(task, data_fraction)| {
                    let mut metrics = vec![Metric::SuccessRate, Metric::Entropy];
                    if kind == TableKind::Prelim {
                        metrics.extend(subtask_metrics(&task, &selected, &subtasks));
                    }
                    Group {
                        task,
                        data_fraction,
                        metrics,
                    }
                })
                .collect()
        })
        .collect();

    // Rows in the paper's order, then methods that are not in the paper by
    // name; a method's evaluated row follows its reported row.
    let row_keys: BTreeSet<RowKey> = index.keys().map(|(r, _, _)| r.clone()).collect();
    let mut row_keys: Vec<RowKey> = row_keys.into_iter().collect();
    row_keys.sort_by_key(|k| {
        let paper_pos = PAPER_METHOD_ORDER.iter().position(|m| *m == k.method);
        (
            paper_pos.is_none(),
            paper_pos.unwrap_or(0),
            k.method.clone(),
            control_rank(k.control.as_deref()),
            k.control.clone(),
            k.source,
            k.initial_states.clone(),
            k.robot_look.clone(),
            k.build.clone(),
        )
    });

    let mut blocks = Vec::new();
    for groups in blocks_groups {
        let mut rows = Vec::new();
        for key in &row_keys {
            let method = &key.method;
            let in_paper = PAPER_METHOD_ORDER.contains(&method.as_str());
            let info = if in_paper {
                paper_info.get(method).copied()
            } else {
                methods.get(method).copied()
            }
            // Unknown methods are treated as history-free without action
            // chunking (k = 1, H = 1): ResultCell does not carry the manifest.
            .unwrap_or(MethodInfo {
                history: 1,
                action_chunking: false,
            });
            let values: Vec<Vec<Option<Value>>> = groups
                .iter()
                .map(|g| {
                    let frac = per_fraction.then(|| fraction_key(g.data_fraction));
                    let cell = index.get(&(key.clone(), g.task.clone(), frac));
                    g.metrics
                        .iter()
                        .map(|m| cell.and_then(|c| value_of(c, m, &subtasks)))
                        .collect()
                })
                .collect();
            if values.iter().flatten().any(Option::is_some) {
                rows.push(Row {
                    method: method.clone(),
                    source: key.source,
                    control: key.control.clone(),
                    initial_states: key.initial_states.clone(),
                    robot_look: key.robot_look.clone(),
                    build: key.build.clone(),
                    info,
                    in_paper,
                    values,
                });
            }
        }
        if !rows.is_empty() {
            blocks.push(Block { groups, rows });
        }
    }

    if kind == TableKind::Main {
        for block in &mut blocks {
            bold_evaluated(block);
        }
    }

    let mut facts = CaptionFacts {
        paper_protocol: paper.protocol.clone(),
        ..CaptionFacts::default()
    };
    for block in &blocks {
        for g in &block.groups {
            if !facts.tasks.contains(&g.task) {
                facts.tasks.push(g.task.clone());
            }
        }
        for row in &block.rows {
            facts.any_dagger |= row.dagger();
            facts.any_ddagger |= row.ddagger();
            for v in row.values.iter().flatten().flatten() {
                facts.any_bold |= v.bold;
                match v.source {
                    Source::Reported => facts.reported_seeds.insert(v.n_seeds),
                    Source::Evaluated => facts.evaluated_seeds.insert(v.n_seeds),
                };
            }
        }
    }

    Ok(TableModel {
        kind,
        obs,
        source,
        blocks,
        facts,
    })
}

fn control_rank(control: Option<&str>) -> u8 {
    match control {
        None => 0,
        // The paper's default (velocity) first, as in its position/velocity table.
        Some("velocity") => 1,
        Some("position") => 2,
        Some(_) => 3,
    }
}

/// Groups per block as (task, data fraction).
fn block_layout(
    kind: TableKind,
    obs: ObsType,
    selected: &[&ResultCell],
) -> Vec<Vec<(String, f64)>> {
    let present: BTreeSet<(u32, String)> =
        selected.iter().map(|c| task_sort_key(&c.task)).collect();
    let present_tasks: Vec<String> = present.into_iter().map(|(_, t)| t).collect();
    let chunk = |tasks: &[String]| -> Vec<Vec<(String, f64)>> {
        tasks
            .chunks(GROUPS_PER_BLOCK)
            .map(|c| c.iter().map(|t| (t.clone(), 1.0)).collect())
            .collect()
    };
    match kind {
        TableKind::Main => {
            let fixed: Vec<&[&str; 3]> = match obs {
                ObsType::State => MAIN_STATE_LAYOUT.iter().collect(),
                ObsType::Image => MAIN_IMAGE_LAYOUT.iter().collect(),
            };
            let mut blocks: Vec<Vec<(String, f64)>> = fixed
                .iter()
                .filter(|b| b.iter().any(|t| present_tasks.iter().any(|p| p == t)))
                .map(|b| b.iter().map(|t| (t.to_string(), 1.0)).collect())
                .collect();
            let extra: Vec<String> = present_tasks
                .iter()
                .filter(|t| !fixed.iter().any(|b| b.contains(&t.as_str())))
                .cloned()
                .collect();
            blocks.extend(chunk(&extra));
            blocks
        }
        TableKind::Datasize => {
            let mut blocks = Vec::new();
            for task in &present_tasks {
                let fractions: BTreeSet<i64> = selected
                    .iter()
                    .filter(|c| &c.task == task)
                    .map(|c| fraction_key(c.data_fraction))
                    .collect();
                let groups: Vec<(String, f64)> = fractions
                    .into_iter()
                    .map(|f| (task.clone(), f as f64 / 1e6))
                    .collect();
                blocks.extend(groups.chunks(GROUPS_PER_BLOCK).map(<[_]>::to_vec));
            }
            blocks
        }
        TableKind::Posvel | TableKind::Prelim => chunk(&present_tasks),
    }
}

/// Arranging sub-task success rates by (method, task), from the paper data:
/// `ResultCell` has no field for them, so they exist for reported rows only.
type Subtasks = BTreeMap<(String, String), Vec<(String, paper::PaperStat)>>;

fn paper_subtasks(paper: &PaperResults) -> Subtasks {
    let mut out = Subtasks::new();
    for r in &paper.results {
        let Some(serde_json::Value::Object(map)) = &r.subtasks else {
            continue;
        };
        let mut names: Vec<&String> = map.keys().collect();
        names.sort_by_key(|n| {
            (
                ARRANGING_SUBTASK_ORDER
                    .iter()
                    .position(|o| o == n)
                    .unwrap_or(usize::MAX),
                n.to_string(),
            )
        });
        let stats: Vec<(String, paper::PaperStat)> = names
            .into_iter()
            .filter_map(|n| {
                let stat = serde_json::from_value(map[n].clone()).ok()?;
                Some((n.clone(), stat))
            })
            .collect();
        out.insert((r.method.clone(), r.task.clone()), stats);
    }
    out
}

fn subtask_metrics(task: &str, selected: &[&ResultCell], subtasks: &Subtasks) -> Vec<Metric> {
    let mut names: Vec<String> = Vec::new();
    for c in selected
        .iter()
        .filter(|c| c.task == task && c.source == Source::Reported)
    {
        if let Some(stats) = subtasks.get(&(c.method.clone(), c.task.clone())) {
            for (n, _) in stats {
                if !names.contains(n) {
                    names.push(n.clone());
                }
            }
        }
    }
    names.into_iter().map(Metric::Subtask).collect()
}

fn value_of(c: &ResultCell, m: &Metric, subtasks: &Subtasks) -> Option<Value> {
    let (stat, bold) = match m {
        Metric::SuccessRate => (c.success_rate, c.bold_success),
        Metric::Entropy => (c.entropy, c.bold_entropy),
        Metric::Subtask(name) => {
            if c.source != Source::Reported {
                return None;
            }
            let stats = subtasks.get(&(c.method.clone(), c.task.clone()))?;
            let (_, s) = stats.iter().find(|(n, _)| n == name)?;
            return Some(Value {
                mean: s.mean,
                std: s.std,
                n_seeds: c.n_seeds,
                bold: s.bold,
                source: c.source,
            });
        }
    };
    Some(Value {
        mean: stat.mean,
        std: stat.std,
        n_seeds: c.n_seeds,
        // Reported rows: bold as the paper printed it. Evaluated rows: decided
        // by `bold_evaluated` for the main table, never bold elsewhere (the
        // paper bolds only its main tables).
        bold: c.source == Source::Reported && bold.unwrap_or(false),
        source: c.source,
    })
}

/// Bold for evaluated values: the best printed value of its column among all
/// rows shown in the same group (history-free k = 1, or history-based k > 1),
/// reported rows included, so a bold evaluated number beats the paper's best.
/// An all-zero column has no best.
fn bold_evaluated(block: &mut Block) {
    for g in 0..block.groups.len() {
        for m in 0..block.groups[g].metrics.len() {
            if !matches!(
                block.groups[g].metrics[m],
                Metric::SuccessRate | Metric::Entropy
            ) {
                continue;
            }
            for history_based in [false, true] {
                let best = block
                    .rows
                    .iter()
                    .filter(|r| r.info.history_based() == history_based)
                    .filter_map(|r| r.values[g][m])
                    .map(|v| numfmt::printed_key(v.mean))
                    .max();
                let Some(best) = best.filter(|b| *b > 0) else {
                    continue;
                };
                for row in block
                    .rows
                    .iter_mut()
                    .filter(|r| r.info.history_based() == history_based)
                {
                    if let Some(v) = row.values[g][m].as_mut() {
                        if v.source == Source::Evaluated {
                            v.bold = numfmt::printed_key(v.mean) == best;
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn task_numbers_and_order() {
        assert_eq!(task_number("Sorting-4 (T4)"), Some(4));
        assert_eq!(task_number("Arranging (T7)"), Some(7));
        assert_eq!(task_number("Whatever"), None);
        let mut t = vec![
            "Stacking-2 (T5)",
            "Avoiding (T1)",
            "Sorting-6 (T4)",
            "Sorting-2 (T4)",
        ];
        t.sort_by_key(|t| task_sort_key(t));
        assert_eq!(
            t,
            [
                "Avoiding (T1)",
                "Sorting-2 (T4)",
                "Sorting-6 (T4)",
                "Stacking-2 (T5)"
            ]
        );
    }
}
