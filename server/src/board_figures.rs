//! What the leaderboard's figures are drawn from, as pure functions of its
//! rows: the points of the Pareto figure and the lines of the data-fraction
//! figure (the `tables` crate draws both).

use crate::leaderboard::{BoardRow, RankGroup};
use d3il_protocol::{ProtocolKind, Source};
use d3il_tables::board::{FractionSeries, ParetoPoint};
use d3il_tables::plot::Est;
use std::collections::{BTreeMap, BTreeSet};

/// Success vs conditional entropy of each row that belongs on the board's
/// Pareto front: quick-protocol smoke tests are left off.
pub fn pareto_points(rows: &[BoardRow]) -> Vec<ParetoPoint> {
    rows.iter()
        .filter(|r| RankGroup::of(r) != RankGroup::Smoke)
        .map(|r| ParetoPoint {
            // The zoo's points are told apart from the paper's.
            label: match r.data_source {
                Some(_) => format!("{} (zoo)", r.method),
                None => r.method.clone(),
            },
            method: r.method.clone(),
            entropy: Est::new(r.entropy.mean, r.entropy.std, r.n_seeds),
            success: Est::new(r.success.mean, r.success.std, r.n_seeds),
            evaluated: r.source == Source::Evaluated,
        })
        .collect()
}

/// One line per method (and task title, where a task has several) through
/// its values at each data fraction.
pub fn fraction_series(rows: &[BoardRow]) -> Vec<FractionSeries> {
    type Points = Vec<(f64, Est, Est)>;
    let mut by: BTreeMap<(String, String), (String, bool, Points)> = BTreeMap::new();
    for r in rows {
        let label = match (r.source, r.protocol) {
            (Source::Reported, _) => r.method.clone(),
            // Quick smoke runs get their own line: never mixed with paper-protocol points.
            (Source::Evaluated, Some(ProtocolKind::Quick)) => {
                format!("{} (evaluated, quick)", r.method)
            }
            // The zoo's rows are a line of their own.
            (Source::Evaluated, _) if r.data_source.is_some() => format!("{} (zoo)", r.method),
            (Source::Evaluated, _) => format!("{} (evaluated)", r.method),
        };
        by.entry((r.task_title.clone(), label))
            .or_insert_with(|| (r.method.clone(), r.source == Source::Evaluated, Vec::new()))
            .2
            .push((
                r.data_fraction,
                Est::new(r.success.mean, r.success.std, r.n_seeds),
                Est::new(r.entropy.mean, r.entropy.std, r.n_seeds),
            ));
    }
    let multi_title = by.keys().map(|k| &k.0).collect::<BTreeSet<_>>().len() > 1;
    by.into_iter()
        .map(|((title, label), (method, evaluated, mut points))| {
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            FractionSeries {
                label: if multi_title {
                    format!("{label} [{title}]")
                } else {
                    label
                },
                method,
                evaluated,
                points,
            }
        })
        .collect()
}
