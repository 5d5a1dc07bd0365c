//! CSV: one line per printed value, with separate mean, std and n_seeds
//! columns; the numbers are the same strings the other formats print.

use crate::model::TableModel;
use crate::numfmt::csv_field;
use d3il_protocol::Source;
use std::fmt::Write;

const HEADER: &str = "table,obs,method,source,history,action_chunking,control,task,data_fraction,metric,mean,std,n_seeds,bold";

pub fn render(m: &TableModel) -> String {
    let mut out = String::new();
    out.push_str(HEADER);
    out.push('\n');
    for block in &m.blocks {
        for row in &block.rows {
            for (g, values) in block.groups.iter().zip(&row.values) {
                for (metric, v) in g.metrics.iter().zip(values) {
                    let Some(v) = v else { continue };
                    let source = match row.source {
                        Source::Reported => "reported",
                        Source::Evaluated => "evaluated",
                    };
                    let _ = writeln!(
                        out,
                        "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                        m.kind,
                        m.obs,
                        csv_field(&row.method),
                        source,
                        row.info.history,
                        row.info.action_chunking,
                        csv_field(row.control.as_deref().unwrap_or("")),
                        csv_field(&g.task),
                        g.data_fraction,
                        metric.csv_name(),
                        v.mean_text(),
                        v.std_text(),
                        v.n_seeds,
                        v.bold
                    );
                }
            }
        }
    }
    out
}
