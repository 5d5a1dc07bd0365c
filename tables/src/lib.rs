//! d3il-tables: regenerates the D3IL paper's result tables (LaTeX, Markdown,
//! CSV) and figures (SVG) from [`ResultCell`]s, the rows the server's store
//! produces for both the paper's reported numbers and our own evaluations.
//!
//! Everything here is a pure function of its input: the same cells give
//! byte-identical output (no clocks, no hash-map iteration, no fonts).
//!
//! Precision policy: reported numbers are printed exactly as the paper's JSON
//! holds them (at least three decimals, more where the paper printed more, e.g.
//! `0.0009`), so the tables reproduce the paper digit for digit; evaluated
//! numbers are printed with three decimals like the paper's.

#![forbid(unsafe_code)]

pub mod board;
mod caption;
pub mod csv;
mod figures;
mod latex;
mod markdown;
mod model;
mod numfmt;
mod panels;
pub mod plot;
pub mod race;
pub mod robustness;
pub mod rollouts;
pub mod summary;
pub mod zoo;

use d3il_protocol::{ObsType, ResultCell, Source};
use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

pub use csv::write_csv;
pub use figures::{render_avoiding_paths, render_figure, FigureKind};
pub use model::{build_table, Block, Group, Metric, Row, TableModel, Value};
pub use numfmt::{mean_std, three_decimals};

/// The caption of a table model in plain (Unicode) text: what is shown, the
/// protocol, the seeds and what the marks and bold mean (the same words the
/// LaTeX and Markdown tables print; the web's main table shows it too).
pub fn caption_text(model: &TableModel) -> String {
    caption::caption(model, caption::Style::Plain)
}

/// Which of the paper's tables to regenerate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum TableKind {
    /// The main results (state- or image-based), paper Tables 2 and 3.
    Main,
    /// Aligning trained on 10/25/50/75/100 % of the demonstrations.
    Datasize,
    /// Position versus velocity control (BESO, DDPM-ACT).
    Posvel,
    /// Preliminary results on Inserting (T6) and Arranging (T7).
    Prelim,
}

impl TableKind {
    pub const ALL: [TableKind; 4] = [
        TableKind::Main,
        TableKind::Datasize,
        TableKind::Posvel,
        TableKind::Prelim,
    ];

    /// The value of `ResultCell::table` for this table.
    pub fn as_str(self) -> &'static str {
        match self {
            TableKind::Main => "main",
            TableKind::Datasize => "datasize",
            TableKind::Posvel => "posvel",
            TableKind::Prelim => "prelim",
        }
    }
}

impl fmt::Display for TableKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for TableKind {
    type Err = TablesError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let norm = s.trim().to_ascii_lowercase();
        TableKind::ALL
            .into_iter()
            .find(|k| k.as_str() == norm)
            .ok_or_else(|| TablesError::Unknown {
                what: "table",
                value: s.to_string(),
                expected: "main, datasize, posvel, prelim",
            })
    }
}

/// Output format of a table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Format {
    Latex,
    Markdown,
    Csv,
}

impl Format {
    pub const ALL: [Format; 3] = [Format::Latex, Format::Markdown, Format::Csv];

    pub fn as_str(self) -> &'static str {
        match self {
            Format::Latex => "latex",
            Format::Markdown => "markdown",
            Format::Csv => "csv",
        }
    }

    /// Conventional file extension.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Latex => "tex",
            Format::Markdown => "md",
            Format::Csv => "csv",
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Format {
    type Err = TablesError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "latex" | "tex" => Ok(Format::Latex),
            "markdown" | "md" => Ok(Format::Markdown),
            "csv" => Ok(Format::Csv),
            _ => Err(TablesError::Unknown {
                what: "format",
                value: s.to_string(),
                expected: "latex, markdown, csv",
            }),
        }
    }
}

/// Which rows to show: the paper's reported numbers, our evaluations, or both.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SourceFilter {
    Reported,
    Evaluated,
    Both,
}

impl SourceFilter {
    pub const ALL: [SourceFilter; 3] = [
        SourceFilter::Reported,
        SourceFilter::Evaluated,
        SourceFilter::Both,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            SourceFilter::Reported => "reported",
            SourceFilter::Evaluated => "evaluated",
            SourceFilter::Both => "both",
        }
    }

    pub fn admits(self, source: Source) -> bool {
        match self {
            SourceFilter::Reported => source == Source::Reported,
            SourceFilter::Evaluated => source == Source::Evaluated,
            SourceFilter::Both => true,
        }
    }
}

impl fmt::Display for SourceFilter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for SourceFilter {
    type Err = TablesError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let norm = s.trim().to_ascii_lowercase();
        SourceFilter::ALL
            .into_iter()
            .find(|k| k.as_str() == norm)
            .ok_or_else(|| TablesError::Unknown {
                what: "source",
                value: s.to_string(),
                expected: "reported, evaluated, both",
            })
    }
}

/// What the tables need to know about a method beyond its cells: the history
/// length decides the bold group (history-free vs history-based) and the
/// double dagger; action chunking decides the dagger.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MethodInfo {
    pub history: u32,
    pub action_chunking: bool,
}

impl MethodInfo {
    /// The paper's second group: methods that condition on a history (k > 1).
    pub fn history_based(&self) -> bool {
        self.history > 1
    }
}

/// Properties of the paper's eleven baselines, from the embedded paper data.
pub fn paper_method_info() -> BTreeMap<String, MethodInfo> {
    d3il_protocol::paper::load_embedded()
        .methods
        .into_iter()
        .map(|(name, m)| {
            let info = MethodInfo {
                history: m.history,
                action_chunking: m.prediction == "action chunk",
            };
            (name, info)
        })
        .collect()
}

#[derive(Debug, thiserror::Error)]
pub enum TablesError {
    #[error("no {filter} results for the {table} table with {obs} observations; {hint}")]
    NoCells {
        table: TableKind,
        obs: ObsType,
        filter: SourceFilter,
        hint: &'static str,
    },
    #[error(
        "two {origin:?} result cells for method `{method}` on {task} ({obs}, data fraction {data_fraction}, control {control}); \
         the database must hold one aggregated cell per method and setting: rename one of the methods"
    )]
    DuplicateCell {
        method: String,
        origin: Source,
        task: String,
        obs: ObsType,
        data_fraction: f64,
        control: String,
    },
    #[error(
        "the result cell of method `{method}` on {task} has a non-finite {what} ({value}); \
         the stored result is corrupt: re-evaluate that submission"
    )]
    NonFinite {
        method: String,
        task: String,
        what: &'static str,
        value: f64,
    },
    #[error("unknown {what} `{value}`; expected one of: {expected}")]
    Unknown {
        what: &'static str,
        value: String,
        expected: &'static str,
    },
    #[error("nothing to draw for the {figure} figure: {hint}")]
    NoFigureData {
        figure: &'static str,
        hint: &'static str,
    },
    #[error(
        "the trace of {rollout} cannot be drawn: {reason}; \
         the stored result is corrupt: re-evaluate that submission"
    )]
    BadTrace { rollout: String, reason: String },
    #[error("could not draw the figure: {0}")]
    Plot(String),
    #[error("could not write the CSV: {0}")]
    Csv(String),
}

/// Renders one of the paper's tables. Methods that are not in the paper are
/// treated as history-free without marks; use [`render_table_with`] to pass
/// their properties.
pub fn render_table(
    cells: &[ResultCell],
    kind: TableKind,
    obs: ObsType,
    format: Format,
    source: SourceFilter,
) -> Result<String, TablesError> {
    render_table_with(cells, kind, obs, format, source, &BTreeMap::new())
}

/// Like [`render_table`], with the properties of methods that are not in the
/// paper (`methods`; entries for the paper's own methods are ignored because
/// their rows stand for the paper's methods).
pub fn render_table_with(
    cells: &[ResultCell],
    kind: TableKind,
    obs: ObsType,
    format: Format,
    source: SourceFilter,
    methods: &BTreeMap<String, MethodInfo>,
) -> Result<String, TablesError> {
    let model = build_table(cells, kind, obs, source, methods)?;
    Ok(match format {
        Format::Latex => latex::render(&model),
        Format::Markdown => markdown::render(&model),
        Format::Csv => csv::render(&model)?,
    })
}
