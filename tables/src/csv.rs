//! CSV: the one CSV writer of the workspace ([`write_csv`]: RFC 4180 quoting
//! by the `csv` crate, and text a spreadsheet would run as a formula made
//! inert), used for the paper tables here and for the server's leaderboard
//! downloads. The table format has one line per printed value, with separate
//! mean, std and n_seeds columns; the numbers are the same strings the other
//! formats print.

use crate::model::TableModel;
use crate::TablesError;
use d3il_protocol::Source;

const HEADER: [&str; 14] = [
    "table",
    "obs",
    "method",
    "source",
    "history",
    "action_chunking",
    "control",
    "task",
    "data_fraction",
    "metric",
    "mean",
    "std",
    "n_seeds",
    "bold",
];

/// A cell that starts like a spreadsheet formula (`=`, `+`, `-`, `@`) and is
/// not a number gets a leading `'`, so opening the file runs nothing
/// (method names and labels come from submitters).
fn formula_guard(s: &str) -> std::borrow::Cow<'_, str> {
    if s.starts_with(['=', '+', '-', '@']) && s.parse::<f64>().is_err() {
        format!("'{s}").into()
    } else {
        s.into()
    }
}

/// Writes a header line and one line per row (`\n`-terminated). Fields are
/// quoted when they hold a comma, a quote or a line break, and guarded
/// against formula injection.
pub fn write_csv<R, F>(header: &[&str], rows: R) -> Result<String, TablesError>
where
    R: IntoIterator<Item = Vec<F>>,
    F: AsRef<str>,
{
    let err = |e: ::csv::Error| TablesError::Csv(e.to_string());
    let mut w = ::csv::WriterBuilder::new()
        .terminator(::csv::Terminator::Any(b'\n'))
        .flexible(false)
        .from_writer(Vec::new());
    w.write_record(header.iter().map(|h| formula_guard(h).into_owned()))
        .map_err(err)?;
    for row in rows {
        w.write_record(row.iter().map(|f| formula_guard(f.as_ref()).into_owned()))
            .map_err(err)?;
    }
    let bytes = w
        .into_inner()
        .map_err(|e| TablesError::Csv(e.to_string()))?;
    String::from_utf8(bytes).map_err(|e| TablesError::Csv(e.to_string()))
}

/// One field as [`write_csv`] writes it.
pub fn csv_field(s: &str) -> String {
    write_csv(&[s], std::iter::empty::<Vec<&str>>())
        .map(|line| line.trim_end_matches('\n').to_string())
        .unwrap_or_default()
}

pub fn render(m: &TableModel) -> Result<String, TablesError> {
    let mut rows = vec![];
    for block in &m.blocks {
        for row in &block.rows {
            for (g, values) in block.groups.iter().zip(&row.values) {
                for (metric, v) in g.metrics.iter().zip(values) {
                    let Some(v) = v else { continue };
                    let source = match row.source {
                        Source::Reported => "reported",
                        Source::Evaluated => "evaluated",
                    };
                    rows.push(vec![
                        m.kind.to_string(),
                        m.obs.to_string(),
                        row.method.clone(),
                        source.to_string(),
                        row.info.history.to_string(),
                        row.info.action_chunking.to_string(),
                        row.control.clone().unwrap_or_default(),
                        g.task.clone(),
                        g.data_fraction.to_string(),
                        metric.csv_name().to_string(),
                        v.mean_text(),
                        v.std_text(),
                        v.n_seeds.to_string(),
                        v.bold.to_string(),
                    ]);
                }
            }
        }
    }
    write_csv(&HEADER, rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quoting_and_the_formula_guard() {
        let out = write_csv(
            &["a", "b"],
            vec![
                vec!["x,y", "say \"hi\""],
                vec!["=HYPERLINK(1)", "-0.5"],
                vec!["line\nbreak", "@me"],
            ],
        )
        .unwrap();
        assert_eq!(
            out,
            "a,b\n\"x,y\",\"say \"\"hi\"\"\"\n'=HYPERLINK(1),-0.5\n\"line\nbreak\",'@me\n"
        );
    }
}
