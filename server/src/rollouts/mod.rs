//! What a policy did, for people: a submission's rollouts
//! filtered by outcome, behaviour and initial state and paged (the failure
//! browser of the API and of the submission page), one rollout's record with
//! its trace (the API's record, the rollout page, the video's replay
//! document), and the pictures drawn from traces (`d3il_tables::rollouts`).
//!
//! Rollouts are named by their number N = initial state × rollouts per state
//! + index ([`RolloutRecord::number`]), as in `d3il replay --rollout N`.

use crate::error::AppError;
use crate::schema;
use crate::state::AppState;
use crate::store::{ResultRow, RolloutRow, SubmissionRow};
use crate::videos::{VideoError, VideoJob};
use d3il_protocol::{
    Ending, FailureReason, ProtocolManifest, RolloutFailure, RolloutRecord, RolloutTrace, TaskId,
};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use utoipa::openapi::schema::{ObjectBuilder, Schema, Type};
use utoipa::openapi::RefOr;
use utoipa::{IntoParams, ToSchema};

/// Why a rollout has no ending or trace to show: its result is older than
/// them (migration 0007).
pub const NOT_RECORDED: &str =
    "not recorded for results stored before 2026-11-26 (server 0.1.0, migration 0007), when rollouts began to keep how they ended and their traces";

/// What the pictures of a submission without traces say.
pub const NOT_RECORDED_SHORT: &str = "no rollout traces: stored before they were recorded";

mod pictures;

/// Default and largest page of the rollout lists.
pub const PER_PAGE: usize = 50;
pub const MAX_PER_PAGE: usize = 500;

/// The outcomes the failure browser filters by.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// The rollout succeeded.
    Success,
    /// It did not (whatever the reason).
    Failure,
    /// It ended because the simulation became unstable.
    Unstable,
    /// It ran to the task's step limit.
    TimeLimit,
}

impl Outcome {
    pub const ALL: [Outcome; 4] = [
        Outcome::Success,
        Outcome::Failure,
        Outcome::Unstable,
        Outcome::TimeLimit,
    ];

    /// The query value (`time_limit`).
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Success => "success",
            Outcome::Failure => "failure",
            Outcome::Unstable => "unstable",
            Outcome::TimeLimit => "time_limit",
        }
    }

    /// Words for people (`time limit`).
    pub fn label(self) -> &'static str {
        match self {
            Outcome::TimeLimit => "time limit",
            o => o.as_str(),
        }
    }

    fn parse(s: &str) -> Result<Outcome, AppError> {
        Outcome::ALL
            .into_iter()
            .find(|o| o.as_str() == s)
            .ok_or_else(|| {
                AppError::invalid(
                    "outcome",
                    format!("unknown outcome `{s}`; use success, failure, unstable or time_limit"),
                )
            })
    }

    /// Whether `row` has this outcome. Rows stored before endings were
    /// recorded ran to the limit when they took the protocol's `max_steps`
    /// without becoming unstable (`Ending::classify`'s rule).
    pub fn holds(self, row: &RolloutRow, max_steps: usize) -> bool {
        let unstable = row
            .failure
            .as_ref()
            .is_some_and(|f| f.reason == FailureReason::SimUnstable)
            || row.ending() == Some(Ending::SimUnstable);
        match self {
            Outcome::Success => row.success,
            Outcome::Failure => !row.success,
            Outcome::Unstable => unstable,
            Outcome::TimeLimit => match row.ending() {
                Some(e) => e == Ending::TimeLimit,
                None => !unstable && row.steps >= max_steps as i64,
            },
        }
    }
}

/// `?outcome=`: the four outcomes.
pub fn outcome_schema() -> RefOr<Schema> {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .description(Some(
            "success, failure (any rollout that did not succeed), unstable (the simulation became unstable) or time_limit (ran to the step limit)",
        ))
        .enum_values(Some(Outcome::ALL.map(Outcome::as_str)))
        .into()
}

/// The query of the rollout lists (`GET /api/v1/submissions/{id}/rollouts`,
/// the submission page's failure browser). Every value is text here so that
/// a bad one gets a message saying what is allowed; empty means not given.
#[derive(Debug, Clone, Default, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct RolloutQuery {
    /// `success`, `failure`, `unstable` or `time_limit`.
    #[param(schema_with = outcome_schema)]
    pub outcome: Option<String>,
    /// A behaviour as the list's `behaviour_label` names it (`1-2-3`, `RB`,
    /// `0`); one of the list's `behaviours`.
    pub behaviour: Option<String>,
    /// An initial state's index.
    #[param(value_type = Option<i64>)]
    pub context: Option<String>,
    /// Page, from 1 (default 1).
    #[param(value_type = Option<i64>)]
    pub page: Option<String>,
    /// Rollouts per page, 1-500 (default 50).
    #[param(value_type = Option<i64>)]
    pub per_page: Option<String>,
}

/// A parsed [`RolloutQuery`].
#[derive(Debug, Clone, PartialEq)]
pub struct RolloutFilter {
    pub outcome: Option<Outcome>,
    pub behaviour: Option<String>,
    pub context: Option<usize>,
    pub page: usize,
    pub per_page: usize,
}

/// Links of one rollout.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RolloutLinks {
    /// The rollout's page (video, pictures, how it ended).
    pub page: String,
    /// Its record with the trace (API).
    pub record: String,
    /// Its video (MP4, made on demand); null without a trace.
    pub video: Option<String>,
    /// The top-down picture (SVG); null without a trace.
    pub paths: Option<String>,
    /// The per-step plots (SVG); null without a trace.
    pub steps: Option<String>,
}

/// One rollout in a list.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RolloutItem {
    /// Initial state × rollouts per state + index.
    pub number: usize,
    /// The initial state's index.
    pub context: usize,
    /// The index within the initial state.
    pub rollout: usize,
    pub success: bool,
    /// The behaviour code (the reference's encoding, per task): an integer,
    /// a list of numbers (Avoiding) or a string, so any JSON value.
    #[schema(value_type = Value)]
    pub behaviour: Value,
    /// The behaviour's name (`d3il_protocol::behaviour_name`).
    pub behaviour_label: String,
    pub steps: i64,
    /// How it ended; null for results stored before endings were recorded.
    #[schema(value_type = Option<schema::Ending>)]
    pub ending: Option<Ending>,
    /// How it ended, in words (or that it was not recorded).
    pub ending_text: String,
    /// `{"reason": "sim_unstable", "message", "step"}` when the simulation
    /// became unstable.
    #[schema(value_type = Option<Object>)]
    pub failure: Option<RolloutFailure>,
    /// A trace is stored (its own, or its initial state's when the policy
    /// was simulated once per state): video and pictures can be made.
    pub has_trace: bool,
    pub links: RolloutLinks,
}

/// How many rollouts have an outcome.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct OutcomeCount {
    #[schema(schema_with = outcome_schema)]
    pub outcome: &'static str,
    pub count: usize,
}

/// The filters a list was made with (as parsed).
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RolloutFilters {
    /// `success`, `failure`, `unstable`, `time_limit`; null: any.
    #[schema(value_type = Option<String>)]
    pub outcome: Option<&'static str>,
    pub behaviour: Option<String>,
    pub context: Option<usize>,
}

/// A page of a submission's rollouts.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RolloutList {
    pub submission_id: i64,
    #[schema(value_type = schema::Task)]
    pub task: TaskId,
    pub rollouts_per_context: usize,
    pub n_contexts: usize,
    /// Rollouts matching the filters (all pages).
    pub total: usize,
    /// Rollouts of the submission.
    pub all: usize,
    pub page: usize,
    pub per_page: usize,
    /// Pages of matching rollouts (0 when none match).
    pub pages: usize,
    pub filters: RolloutFilters,
    /// Every behaviour name among the submission's rollouts (what
    /// `behaviour=` accepts).
    pub behaviours: Vec<String>,
    /// Rollouts per outcome, over all of the submission's rollouts.
    pub outcomes: Vec<OutcomeCount>,
    /// Why no rollout has a trace, when none has.
    pub traces_note: Option<String>,
    pub items: Vec<RolloutItem>,
}

/// One rollout's record with its trace. With `manifest`, `rollouts` is the
/// document `d3il replay --result FILE --rollout N` reads.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RolloutDetail {
    pub submission_id: i64,
    pub number: usize,
    #[schema(value_type = schema::Task)]
    pub task: TaskId,
    /// The result's protocol manifest.
    #[schema(value_type = Object)]
    pub manifest: ProtocolManifest,
    /// The one record, with its trace (packed arrays: little-endian f32/u32,
    /// deflated, base64; the trace of a copy of a rollout simulated once is
    /// its initial state's).
    #[schema(value_type = Vec<Object>)]
    pub rollouts: Vec<RolloutRecord>,
    /// The rollout as the lists show it.
    pub summary: RolloutItem,
    /// The actions the environment received, one row per step, unpacked
    /// from the trace; null without a trace.
    pub actions: Option<Vec<Vec<f32>>>,
    /// Why there is no trace, when there is none.
    pub trace_note: Option<String>,
}

/// A finished submission's rollouts, as stored.
pub struct Rollouts {
    pub submission: SubmissionRow,
    pub result: ResultRow,
    pub manifest: ProtocolManifest,
    pub rows: Vec<RolloutRow>,
    /// Initial states whose rollout 0 holds a trace.
    zero_traced: BTreeSet<i64>,
}

impl Rollouts {
    /// Submission `id`'s rollouts: 404 while it has no result.
    pub async fn load(state: &AppState, id: i64) -> Result<Rollouts, AppError> {
        let submission = state.store.submission(id).await?;
        let result = state.store.result_for(id).await?.ok_or_else(|| {
            AppError::NotFound(format!(
                "submission {id} has no results yet (status: {}); poll /api/v1/submissions/{id}",
                submission.status
            ))
        })?;
        let rows = state.store.rollouts_for(id).await?;
        Rollouts::from_parts(submission, result, rows)
    }

    /// From rows already read.
    pub fn from_parts(
        submission: SubmissionRow,
        result: ResultRow,
        rows: Vec<RolloutRow>,
    ) -> Result<Rollouts, AppError> {
        let manifest = result.manifest().ok_or_else(|| {
            AppError::Internal(format!(
                "submission {}: stored manifest does not parse",
                submission.id
            ))
        })?;
        let zero_traced = rows
            .iter()
            .filter(|r| r.rollout_index == 0 && r.has_trace)
            .map(|r| r.context_index)
            .collect();
        Ok(Rollouts {
            submission,
            result,
            manifest,
            rows,
            zero_traced,
        })
    }

    fn id(&self) -> i64 {
        self.submission.id
    }

    pub fn per_context(&self) -> usize {
        self.manifest.rollouts_per_context.max(1)
    }

    pub fn number(&self, row: &RolloutRow) -> usize {
        row.context_index as usize * self.per_context() + row.rollout_index as usize
    }

    /// Rollout number `n`: 404 naming the numbers there are.
    pub fn row(&self, n: usize) -> Result<&RolloutRow, AppError> {
        self.rows
            .iter()
            .find(|r| self.number(r) == n)
            .ok_or_else(|| {
                AppError::NotFound(format!(
                    "submission {} has no rollout {n}; its rollouts are numbered 0 to {}",
                    self.id(),
                    self.rows.len().saturating_sub(1)
                ))
            })
    }

    /// Which stored row holds `row`'s trace, as (initial state, index): its
    /// own, or, for a copy of a rollout simulated once per initial state
    /// (`manifest.simulated_once`), its state's rollout 0. The stored-row
    /// form of `EvalResult::trace_of`, the one place this rule is applied
    /// to stored rows.
    pub fn trace_holder(&self, row: &RolloutRow) -> Option<(i64, i64)> {
        if row.has_trace {
            Some((row.context_index, row.rollout_index))
        } else if self.manifest.simulated_once && self.zero_traced.contains(&row.context_index) {
            Some((row.context_index, 0))
        } else {
            None
        }
    }

    /// Whether any rollout has a trace.
    pub fn any_trace(&self) -> bool {
        self.rows.iter().any(|r| r.has_trace)
    }

    pub fn label(&self, row: &RolloutRow) -> String {
        d3il_protocol::behaviour_name(self.submission.task, &row.behaviour.0)
    }

    /// Every behaviour name among the rollouts, sorted.
    pub fn behaviour_labels(&self) -> Vec<String> {
        let set: BTreeSet<String> = self.rows.iter().map(|r| self.label(r)).collect();
        set.into_iter().collect()
    }

    /// Parses `q` for this submission: a value naming nothing is a 400 that
    /// says what is allowed.
    pub fn filter(&self, q: &RolloutQuery) -> Result<RolloutFilter, AppError> {
        fn given(v: &Option<String>) -> Option<&str> {
            v.as_deref().map(str::trim).filter(|v| !v.is_empty())
        }
        let outcome = given(&q.outcome).map(Outcome::parse).transpose()?;
        let n_contexts = self.manifest.n_contexts;
        let context = given(&q.context)
            .map(|c| {
                c.parse::<usize>()
                    .ok()
                    .filter(|c| *c < n_contexts)
                    .ok_or_else(|| {
                        AppError::invalid(
                            "context",
                            format!(
                                "`context` must be an initial state's index, 0 to {}, got `{c}`",
                                n_contexts.saturating_sub(1)
                            ),
                        )
                    })
            })
            .transpose()?;
        let behaviour = match given(&q.behaviour) {
            None => None,
            Some(b) => {
                let labels = self.behaviour_labels();
                if !labels.iter().any(|l| l == b) {
                    return Err(AppError::invalid(
                        "behaviour",
                        format!(
                            "no rollout of submission {} has behaviour `{b}`; its behaviours are {}",
                            self.id(),
                            labels.join(", ")
                        ),
                    ));
                }
                Some(b.to_string())
            }
        };
        let number = |field: &str, v: Option<&str>, default: usize, max: usize| {
            v.map_or(Ok(default), |v| {
                v.parse::<usize>()
                    .ok()
                    .filter(|n| (1..=max).contains(n))
                    .ok_or_else(|| {
                        let range = if max == usize::MAX {
                            "from 1".to_string()
                        } else {
                            format!("from 1 to {max}")
                        };
                        AppError::invalid(
                            field,
                            format!("`{field}` must be a whole number {range}, got `{v}`"),
                        )
                    })
            })
        };
        Ok(RolloutFilter {
            outcome,
            behaviour,
            context,
            page: number("page", given(&q.page), 1, usize::MAX)?,
            per_page: number("per_page", given(&q.per_page), PER_PAGE, MAX_PER_PAGE)?,
        })
    }

    /// The summary of one rollout.
    pub fn item(&self, row: &RolloutRow) -> RolloutItem {
        let (id, n) = (self.id(), self.number(row));
        let traced = self.trace_holder(row).is_some();
        let api = format!("/api/v1/submissions/{id}/rollouts/{n}");
        let ending = row.ending();
        RolloutItem {
            number: n,
            context: row.context_index as usize,
            rollout: row.rollout_index as usize,
            success: row.success,
            behaviour: row.behaviour.0.clone(),
            behaviour_label: self.label(row),
            steps: row.steps,
            ending,
            ending_text: ending.map_or_else(
                || format!("how it ended is {NOT_RECORDED}"),
                |e| e.describe().to_string(),
            ),
            failure: row.failure.as_ref().map(|f| f.0.clone()),
            has_trace: traced,
            links: RolloutLinks {
                page: format!("/submissions/{id}/rollouts/{n}"),
                video: traced.then(|| format!("{api}/video")),
                paths: traced.then(|| format!("/plots/submissions/{id}/rollouts/{n}/paths.svg")),
                steps: traced.then(|| format!("/plots/submissions/{id}/rollouts/{n}/steps.svg")),
                record: api,
            },
        }
    }

    /// The rollouts matching `f`, its page of them.
    pub fn list(&self, f: &RolloutFilter) -> Result<RolloutList, AppError> {
        let max_steps = self.manifest.max_steps;
        let matching: Vec<&RolloutRow> = self
            .rows
            .iter()
            .filter(|r| f.outcome.is_none_or(|o| o.holds(r, max_steps)))
            .filter(|r| f.context.is_none_or(|c| r.context_index as usize == c))
            .filter(|r| f.behaviour.as_ref().is_none_or(|b| &self.label(r) == b))
            .collect();
        let pages = matching.len().div_ceil(f.per_page);
        if f.page > pages.max(1) {
            return Err(AppError::invalid(
                "page",
                format!(
                    "page {} is past the last page ({}) of these {} rollouts",
                    f.page,
                    pages.max(1),
                    matching.len()
                ),
            ));
        }
        let items = matching
            .iter()
            .skip((f.page - 1) * f.per_page)
            .take(f.per_page)
            .map(|r| self.item(r))
            .collect();
        let mut counts: BTreeMap<&'static str, usize> = BTreeMap::new();
        for o in Outcome::ALL {
            counts.insert(
                o.as_str(),
                self.rows.iter().filter(|r| o.holds(r, max_steps)).count(),
            );
        }
        Ok(RolloutList {
            submission_id: self.id(),
            task: self.submission.task,
            rollouts_per_context: self.per_context(),
            n_contexts: self.manifest.n_contexts,
            total: matching.len(),
            all: self.rows.len(),
            page: f.page,
            per_page: f.per_page,
            pages,
            filters: RolloutFilters {
                outcome: f.outcome.map(Outcome::as_str),
                behaviour: f.behaviour.clone(),
                context: f.context,
            },
            behaviours: self.behaviour_labels(),
            outcomes: Outcome::ALL
                .iter()
                .map(|o| OutcomeCount {
                    outcome: o.as_str(),
                    count: counts[o.as_str()],
                })
                .collect(),
            traces_note: (!self.any_trace()).then(|| format!("rollout traces are {NOT_RECORDED}")),
            items,
        })
    }

    /// The trace of `row` (see [`Rollouts::trace_holder`]).
    pub async fn trace(
        &self,
        state: &AppState,
        row: &RolloutRow,
    ) -> Result<Option<RolloutTrace>, AppError> {
        let Some((c, i)) = self.trace_holder(row) else {
            return Ok(None);
        };
        Ok(state.store.rollout_trace(self.id(), c, i).await?)
    }

    /// Rollout `n`'s record, its trace resolved.
    pub async fn record(&self, state: &AppState, n: usize) -> Result<RolloutRecord, AppError> {
        let mut record = self.record_without_trace(n)?;
        record.trace = self.trace(state, self.row(n)?).await?.map(Box::new);
        Ok(record)
    }

    /// Rollout `n`'s record as stored, without its trace.
    pub fn record_without_trace(&self, n: usize) -> Result<RolloutRecord, AppError> {
        let row = self.row(n)?;
        Ok(RolloutRecord {
            context_index: row.context_index as usize,
            rollout_index: row.rollout_index as usize,
            success: row.success,
            behaviour: row.behaviour.0.clone(),
            steps: row.steps as usize,
            path: row.path_json.as_ref().map(|p| p.0.clone()),
            failure: row.failure.as_ref().map(|f| f.0.clone()),
            ending: row.ending(),
            trace: None,
        })
    }

    /// Rollout `n` as the API's record shows it.
    pub async fn detail(&self, state: &AppState, n: usize) -> Result<RolloutDetail, AppError> {
        let record = self.record(state, n).await?;
        let actions = match &record.trace {
            Some(t) => Some(
                t.unpack()
                    .map_err(|e| {
                        AppError::Internal(format!(
                            "submission {} rollout {n}: stored trace does not unpack: {e}",
                            self.id()
                        ))
                    })?
                    .actions,
            ),
            None => None,
        };
        Ok(RolloutDetail {
            submission_id: self.id(),
            number: n,
            task: self.submission.task,
            manifest: self.manifest.clone(),
            summary: self.item(self.row(n)?),
            trace_note: record.trace.is_none().then(|| self.no_trace_note()),
            actions,
            rollouts: vec![record],
        })
    }

    /// Why a rollout has no trace.
    pub fn no_trace_note(&self) -> String {
        if self.any_trace() {
            "this rollout's trace was not stored".into()
        } else {
            format!("rollout traces are {NOT_RECORDED}")
        }
    }

    /// Rollout `n`'s video (made by `d3il replay` in the render pool, or
    /// from the cache): its file.
    pub async fn video(&self, state: &AppState, n: usize) -> Result<std::path::PathBuf, AppError> {
        let record = self.record(state, n).await?;
        if record.trace.is_none() {
            return Err(AppError::NotFound(format!(
                "rollout {n} of submission {} has no video: {}",
                self.id(),
                self.no_trace_note()
            )));
        }
        let document = serde_json::to_string(&serde_json::json!({
            "manifest": &self.manifest,
            "rollouts": [&record],
        }))
        .map_err(|e| AppError::Internal(format!("replay document: {e}")))?;
        let job = VideoJob {
            submission_id: self.id(),
            number: n,
            document,
            mjcf_sha256: self.manifest.mjcf_sha256.clone(),
        };
        state.videos.video(job).await.map_err(|e| match e {
            VideoError::Refused(m) => AppError::NotRendered(format!(
                "the video of rollout {n} of submission {} could not be made: {m}",
                self.id()
            )),
            VideoError::Busy(_) => AppError::Busy {
                retry_after: 30,
                reason: "too many videos are waiting to be rendered",
            },
            e @ VideoError::Broken(_) => AppError::Internal(e.to_string()),
        })
    }
}
