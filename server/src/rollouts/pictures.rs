//! The pictures of what rollouts did, drawn by `d3il_tables::rollouts` from
//! the stored traces: one rollout from above and its per-step signals, every
//! rollout's TCP path overlaid, the map of initial states. A rollout or
//! submission without traces gets the tables' "no data" picture saying why.

use super::{Rollouts, NOT_RECORDED_SHORT};
use crate::cache::Rendered;
use crate::error::AppError;
use crate::state::AppState;
use d3il_protocol::{EvalResult, RolloutRecord, RolloutTrace};
use d3il_tables::rollouts as draw;
use d3il_tables::TablesError;

/// A drawn picture, or the tables' "no data" picture when there was
/// nothing to draw.
fn drawn(title: &str, svg: Result<String, TablesError>) -> Result<String, AppError> {
    match svg {
        Ok(svg) => Ok(svg),
        Err(e @ TablesError::NoFigureData { .. }) => Ok(draw::no_data_svg(title, &e.to_string())),
        Err(e) => Err(AppError::Internal(format!("{title}: {e}"))),
    }
}

impl Rollouts {
    /// The record of rollout `n` with its trace, or the "no data" picture.
    async fn traced(
        &self,
        state: &AppState,
        n: usize,
        title: &str,
    ) -> Result<Result<(RolloutRecord, RolloutTrace), String>, AppError> {
        let mut record = self.record(state, n).await?;
        Ok(match record.trace.take() {
            Some(t) => Ok((record, *t)),
            None => Err(draw::no_data_svg(title, &self.no_trace_note())),
        })
    }

    /// Rollout `n` seen from above (TCP and object paths over the scene).
    pub async fn top_down_svg(&self, state: &AppState, n: usize) -> Result<String, AppError> {
        let title = format!("Submission {}, rollout {n}: seen from above", self.id());
        match self.traced(state, n, &title).await? {
            Ok((record, trace)) => drawn(
                &title,
                draw::top_down_svg(self.submission.task, &record, &trace),
            ),
            Err(no_data) => Ok(no_data),
        }
    }

    /// Rollout `n`'s signals step by step.
    pub async fn step_plots_svg(&self, state: &AppState, n: usize) -> Result<String, AppError> {
        let title = format!("Submission {}, rollout {n}: step by step", self.id());
        match self.traced(state, n, &title).await? {
            Ok((record, trace)) => drawn(
                &title,
                draw::step_plots_svg(self.submission.task, &record, &trace),
            ),
            Err(no_data) => Ok(no_data),
        }
    }

    /// Every simulated rollout's TCP path, by behaviour (the copies of a
    /// rollout simulated once are drawn once: they are the same path).
    /// Drawn once per result: a stored result never changes.
    pub async fn overlay_svg(&self, state: &AppState) -> Result<String, AppError> {
        if let Some(svg) = state.finished.get(Rendered::Overlay, self.id()) {
            return Ok(svg.to_string());
        }
        let svg = self.draw_overlay(state).await?;
        Ok(state
            .finished
            .put(Rendered::Overlay, self.id(), svg)
            .to_string())
    }

    async fn draw_overlay(&self, state: &AppState) -> Result<String, AppError> {
        let title = format!("Submission {}: every rollout's path", self.id());
        if !self.any_trace() {
            return Ok(draw::no_data_svg(&title, NOT_RECORDED_SHORT));
        }
        let traces = state.store.rollout_traces(self.id(), false).await?;
        let mut records = vec![];
        for (c, i, t) in traces {
            let n = c as usize * self.per_context() + i as usize;
            let mut r = self.record_without_trace(n)?;
            r.trace = Some(Box::new(t));
            records.push(r);
        }
        let pairs: Vec<(&RolloutRecord, &RolloutTrace)> = records
            .iter()
            .filter_map(|r| r.trace.as_deref().map(|t| (r, t)))
            .collect();
        drawn(&title, draw::overlay_svg(self.submission.task, &pairs))
    }

    /// The initial states by success rate and dominant behaviour (drawn
    /// once per result).
    pub async fn start_map_svg(&self, state: &AppState) -> Result<String, AppError> {
        if let Some(svg) = state.finished.get(Rendered::StartMap, self.id()) {
            return Ok(svg.to_string());
        }
        let svg = self.draw_start_map(state).await?;
        Ok(state
            .finished
            .put(Rendered::StartMap, self.id(), svg)
            .to_string())
    }

    async fn draw_start_map(&self, state: &AppState) -> Result<String, AppError> {
        let title = format!("Submission {}: initial states", self.id());
        if !self.any_trace() {
            return Ok(draw::no_data_svg(&title, NOT_RECORDED_SHORT));
        }
        let result = self.eval_result(state).await?;
        let starts = draw::start_states(self.submission.task, &result);
        drawn(&title, draw::start_map_svg(self.submission.task, &starts))
    }

    /// The stored result as the worker made it, with the traces of each
    /// initial state's rollout 0 (what [`draw::start_states`] reads).
    async fn eval_result(&self, state: &AppState) -> Result<EvalResult, AppError> {
        let r = &self.result;
        let mut firsts: std::collections::BTreeMap<i64, RolloutTrace> = state
            .store
            .rollout_traces(self.id(), true)
            .await?
            .into_iter()
            .map(|(c, _, t)| (c, t))
            .collect();
        let mut rollouts = vec![];
        for row in &self.rows {
            let mut record = self.record_without_trace(self.number(row))?;
            if row.rollout_index == 0 {
                record.trace = firsts.remove(&row.context_index).map(Box::new);
            }
            rollouts.push(record);
        }
        Ok(EvalResult {
            manifest: self.manifest.clone(),
            metrics: r.metrics(),
            per_context: r.per_context_json.0.clone(),
            rollouts,
            rollouts_ended_unstable: r.rollouts_ended_unstable as usize,
        })
    }
}
