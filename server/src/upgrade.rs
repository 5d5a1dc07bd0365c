//! What a start does to results stored by an earlier build, before serving
//! (docs/intervals.md): every result and robustness document computed under interval
//! rules older than this build's (`d3il_metrics::recompute::RULES_VERSION`)
//! gets its intervals recomputed from its rollout records
//! (`d3il_metrics::recompute`) and written back with the rules it now
//! follows, so a page never shows an interval of a method the service no
//! longer uses. Runs once per row: the next start finds nothing to do.

use crate::store::{Store, StoreError};
use d3il_metrics::recompute::{recompute_intervals, recompute_robustness, RULES_VERSION};
use d3il_protocol::robustness::RobustnessResult;

/// How many stored results and robustness documents a start recomputed.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Recomputed {
    pub results: usize,
    pub robustness: usize,
    /// Rows that could not be recomputed (submission id, why); kept as they
    /// were, and tried again at the next start.
    pub failed: Vec<(i64, String)>,
}

/// Recomputes every row below [`RULES_VERSION`] (see the module docs).
pub async fn recompute_stored_intervals(store: &Store) -> Result<Recomputed, StoreError> {
    let (results, robustness) = store.results_before_rules(RULES_VERSION).await?;
    let mut out = Recomputed::default();
    for id in results {
        let Some(mut r) = store.eval_result(id).await? else {
            continue;
        };
        match recompute_intervals(&mut r) {
            Ok(()) => {
                store.update_result_intervals(id, &r, RULES_VERSION).await?;
                out.results += 1;
            }
            Err(e) => out.failed.push((id, e.to_string())),
        }
    }
    for id in robustness {
        let Some(text) = store.robustness_document(id).await? else {
            continue;
        };
        let mut doc: RobustnessResult = match serde_json::from_str(&text) {
            Ok(d) => d,
            Err(e) => {
                out.failed
                    .push((id, format!("robustness document does not parse: {e}")));
                continue;
            }
        };
        match recompute_robustness(&mut doc) {
            Ok(()) => {
                store
                    .update_robustness_intervals(id, &doc, RULES_VERSION)
                    .await?;
                out.robustness += 1;
            }
            Err(e) => out.failed.push((id, e.to_string())),
        }
    }
    if out.results + out.robustness > 0 {
        tracing::info!(
            results = out.results,
            robustness = out.robustness,
            "recomputed the intervals of results stored under earlier rules (docs/intervals.md)"
        );
    }
    for (id, why) in &out.failed {
        tracing::warn!(submission = id, "intervals not recomputed: {why}");
    }
    Ok(out)
}
