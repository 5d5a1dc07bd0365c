//! Results stored under earlier interval rules (migration 0014, docs/intervals.md):
//! which ones, and writing back their recomputed intervals. The
//! recomputation itself is `d3il_metrics::recompute`'s; the server runs it
//! at start-up (`crate::upgrade`).

use super::results::IntervalNotes;
use super::{to_json, Store, StoreError};
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::EvalResult;

impl Store {
    /// Submissions whose result, or robustness document, was computed
    /// under interval rules older than `rules` (NULL: before 0.5.0).
    pub async fn results_before_rules(
        &self,
        rules: i64,
    ) -> Result<(Vec<i64>, Vec<i64>), StoreError> {
        let results: Vec<i64> = on_db!(&self.db, pool => sqlx::query_scalar(
            "SELECT submission_id FROM results WHERE intervals_rules IS NULL OR intervals_rules < $1 \
             ORDER BY submission_id",
        )
        .bind(rules)
        .fetch_all(pool)
        .await)?;
        let robustness: Vec<i64> = on_db!(&self.db, pool => sqlx::query_scalar(
            "SELECT submission_id FROM robustness_results WHERE intervals_rules IS NULL OR intervals_rules < $1 \
             ORDER BY submission_id",
        )
        .bind(rules)
        .fetch_all(pool)
        .await)?;
        Ok((results, robustness))
    }

    /// Writes a result's recomputed metrics (values, intervals, their
    /// methods), per-state breakdown and the rules they were computed under.
    /// Rollout records are not touched.
    pub async fn update_result_intervals(
        &self,
        submission_id: i64,
        r: &EvalResult,
        rules: i64,
    ) -> Result<(), StoreError> {
        let m = &r.metrics;
        on_db!(&self.db, pool => { sqlx::query(
            "UPDATE results SET success_rate = $1, success_ci_low = $2, success_ci_high = $3, \
             behaviour_entropy = $4, behaviour_ci_low = $5, behaviour_ci_high = $6, conditional_entropy = $7, \
             conditional_ci_low = $8, conditional_ci_high = $9, stacking_levels_json = $10, per_context_json = $11, \
             intervals_json = $12, intervals_rules = $13 WHERE submission_id = $14",
        )
        .bind(m.success_rate.value)
        .bind(m.success_rate.ci_low)
        .bind(m.success_rate.ci_high)
        .bind(m.behaviour_entropy.value)
        .bind(m.behaviour_entropy.ci_low)
        .bind(m.behaviour_entropy.ci_high)
        .bind(m.conditional_entropy.value)
        .bind(m.conditional_entropy.ci_low)
        .bind(m.conditional_entropy.ci_high)
        .bind(m.stacking_levels.map(|s| to_json(&s)))
        .bind(to_json(&r.per_context))
        .bind(to_json(&IntervalNotes::of(m)))
        .bind(rules)
        .bind(submission_id)
        .execute(pool)
        .await?; });
        Ok(())
    }

    /// Writes a robustness document recomputed under `rules` (document,
    /// summary and overall score).
    pub async fn update_robustness_intervals(
        &self,
        submission_id: i64,
        doc: &RobustnessResult,
        rules: i64,
    ) -> Result<(), StoreError> {
        let encode = |what: &str, v: &RobustnessResult| {
            serde_json::to_string(v)
                .map_err(|e| StoreError::Corrupt(format!("robustness {what} not encoded: {e}")))
        };
        let document = encode("document", doc)?;
        let summary = encode("summary", &super::summary_of(doc))?;
        on_db!(&self.db, pool => { sqlx::query(
            "UPDATE robustness_results SET overall = $1, overall_ci_low = $2, overall_ci_high = $3, \
             summary_json = $4, document_json = $5, intervals_rules = $6 WHERE submission_id = $7",
        )
        .bind(doc.overall.map(|e| e.value))
        .bind(doc.overall.map(|e| e.ci_low))
        .bind(doc.overall.map(|e| e.ci_high))
        .bind(summary)
        .bind(document)
        .bind(rules)
        .bind(submission_id)
        .execute(pool)
        .await?; });
        Ok(())
    }
}
