//! A submission's page (status, progress, metrics, figures, its other seeds)
//! and its JSON download.

use super::format::{fmt_duration, fmt_num, fmt_time};
use super::render;
use super::rollouts::{browser as rollout_browser, Browser};
use crate::error::{AppError, PageError};
use crate::http::extract::Param;
use crate::http::extract::Query;
use crate::leaderboard::{behaviour_counts, protocol_str};
use crate::rollouts::{RolloutQuery, Rollouts};
use crate::state::AppState;
use crate::store::{PolicyKind, SubmissionRow, SubmissionStatus};
use crate::views::{progress, submission_view};
use askama::Template;
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use d3il_protocol::{ObsType, TaskId};
use d3il_tables::{board as figures, render_avoiding_paths};

struct ContextLine {
    index: usize,
    success: String,
    entropy: String,
    behaviours: String,
}

struct SeedLine {
    id: i64,
    seed: i64,
    status: String,
    success: String,
    this: bool,
}

struct MetricLine {
    name: &'static str,
    value: String,
    ci: String,
    /// The interval's method, or why there is none.
    method: String,
}

#[derive(Template)]
#[template(path = "submission.html")]
struct SubmissionPage {
    s: SubmissionRow,
    live: bool,
    attempts: String,
    progress_done: i64,
    progress_total: i64,
    queue_position: Option<i64>,
    eta: Option<String>,
    metrics: Vec<MetricLine>,
    contexts: Vec<ContextLine>,
    seeds: Vec<SeedLine>,
    manifest: String,
    protocol_manifest: String,
    sandbox: String,
    paths_svg: Option<String>,
    /// Every rollout's path (from traces), and the initial-state map.
    overlay_svg: Option<String>,
    starts_svg: Option<String>,
    behaviours_svg: Option<String>,
    /// The failure browser, once there is a result.
    browser: Option<Browser>,
    created: String,
    policy: String,
    /// `paper` or `quick`.
    protocol_name: &'static str,
    /// The initial-state set and where it comes from, once there is a result.
    initial_states: Option<String>,
    /// Image results: how the robot was drawn.
    robot_look: Option<String>,
    /// (rollouts ended unstable, rollouts), once there is a result.
    unstable: Option<(i64, usize)>,
    /// More than half of the rollouts ended with an unstable simulation.
    mostly_unstable: bool,
    /// Sorting results carry the protocol caveat of docs/tasks.md.
    sorting: bool,
    /// The success rate so far and its confidence sequence.
    so_far: Option<SoFar>,
    /// Who cancelled the evaluation, when it was.
    cancelled_by: Option<String>,
    /// (when, by whom, why) an admin withdrew it.
    withdrawn: Option<(String, String, String)>,
    /// A suite submission's scores, once its robustness document is stored.
    robustness: Option<RobustnessScores>,
}

/// A suite submission's robustness scores as its page shows them.
struct RobustnessScores {
    /// (axis, score with interval) in the suite's order.
    axes: Vec<(String, String)>,
    overall: String,
    /// The label of the score intervals when their measured coverage is
    /// below the nominal 95 % (too few initial states).
    coverage: Option<String>,
}

fn robustness_scores(doc: &d3il_protocol::robustness::RobustnessResult) -> RobustnessScores {
    use d3il_tables::robustness::interval_text;
    RobustnessScores {
        axes: doc
            .axes
            .iter()
            .map(|a| (a.axis.to_string(), interval_text(&a.score)))
            .collect(),
        overall: interval_text(&doc.overall),
        coverage: doc.score_coverage().map(|c| c.label),
    }
}

/// The live estimate as the page shows it.
struct SoFar {
    rate: String,
    cs: String,
    states: u64,
    rollouts: u64,
    successes: u64,
    level: String,
    partial: bool,
}

fn so_far(e: &crate::live::LiveEstimate) -> SoFar {
    SoFar {
        rate: e.success_rate.map_or_else(|| "—".into(), fmt_num),
        cs: format!("[{}, {}]", fmt_num(e.cs_low), fmt_num(e.cs_high)),
        states: e.states,
        rollouts: e.rollouts,
        successes: e.successes,
        level: format!("{}", ((1.0 - e.alpha) * 100.0).round()),
        partial: e.partial,
    }
}

fn pretty<T: serde::Serialize>(v: &T) -> String {
    serde_json::to_string_pretty(v).unwrap_or_default()
}

pub(super) async fn submission_page(
    State(state): State<AppState>,
    Param(id): Param<i64>,
    Query(q): Query<RolloutQuery>,
) -> Result<Response, PageError> {
    let store = &state.store;
    let s = store.submission(id).await?;
    let job = store.job_for(id).await?;
    let p = progress(&state, &job, &s).await?;
    let result = store.result_for(id).await?;
    let cancelled = store.cancelled(id).await?;
    let live_estimate = crate::live::live_estimate(store, id, cancelled.is_some()).await?;
    let mut metrics = vec![];
    let mut contexts = vec![];
    let mut protocol_manifest = String::new();
    let mut initial_states = None;
    let mut robot_look = None;
    let mut unstable = None;
    let mut paths_svg = None;
    let mut overlay_svg = None;
    let mut starts_svg = None;
    let mut behaviours_svg = None;
    let mut browser = None;
    let mut bad_query = false;
    if let Some(r) = &result {
        let m = r.metrics();
        let line = |name, e: d3il_protocol::Estimate| MetricLine {
            name,
            value: fmt_num(e.value),
            ci: match e.interval() {
                Some((lo, hi)) => format!("[{}, {}]", fmt_num(lo), fmt_num(hi)),
                None => "no interval".into(),
            },
            method: e.interval_note(),
        };
        metrics = vec![
            line("Success rate", m.success_rate),
            line("Conditional behaviour entropy", m.conditional_entropy),
            line("Behaviour entropy H(π(β))", m.behaviour_entropy),
            MetricLine {
                name: "Inference time per query (ms)",
                value: format!("{:.2}", r.inference_ms),
                ci: String::new(),
                method: String::new(),
            },
        ];
        let levels = r.stacking_levels_json.as_ref().map(|j| j.0);
        if let Some(levels) = levels {
            const NAMES: [[&str; 3]; 3] = [
                [
                    "Stacking-1 (≥ 1 box): success rate",
                    "Stacking-1: conditional behaviour entropy",
                    "Stacking-1: behaviour entropy H(π(β))",
                ],
                [
                    "Stacking-2 (≥ 2 boxes): success rate",
                    "Stacking-2: conditional behaviour entropy",
                    "Stacking-2: behaviour entropy H(π(β))",
                ],
                [
                    "Stacking-3 (full stack): success rate",
                    "Stacking-3: conditional behaviour entropy",
                    "Stacking-3: behaviour entropy H(π(β))",
                ],
            ];
            for (l, names) in levels.iter().zip(NAMES) {
                for (e, name) in [l.success_rate, l.conditional_entropy, l.behaviour_entropy]
                    .into_iter()
                    .zip(names)
                {
                    metrics.push(line(name, e));
                }
            }
        } else if let Some(st) = r.stacking_json.as_ref().map(|j| j.0) {
            // Stored before the levels carried their own entropies.
            for (k, name) in [
                "Stacking: ≥ 1 box",
                "Stacking: ≥ 2 boxes",
                "Stacking: 3 boxes",
            ]
            .into_iter()
            .enumerate()
            {
                metrics.push(MetricLine {
                    name,
                    value: fmt_num(st[k]),
                    ci: String::new(),
                    method: String::new(),
                });
            }
        }
        contexts = r
            .per_context_json
            .iter()
            .map(|c| ContextLine {
                index: c.context_index,
                success: fmt_num(c.success_rate),
                entropy: fmt_num(c.conditional_entropy),
                behaviours: c
                    .behaviours
                    .iter()
                    .map(|(b, n)| format!("{b}×{n}"))
                    .collect::<Vec<_>>()
                    .join(", "),
            })
            .collect();
        protocol_manifest = pretty(&r.manifest_json);
        initial_states = r.manifest().map(|m| {
            format!(
                "{} ({}), sha256 {}",
                m.initial_states_name(),
                m.initial_states_origin(),
                m.initial_states_sha256
            )
        });
        robot_look = r
            .manifest()
            .filter(|m| m.obs_type == ObsType::Image)
            .map(|m| match m.robot_look_note() {
                Some(note) => note.text.to_string(),
                None => "robot drawn with the Panda's meshes, as the original draws it".into(),
            });
        let rollouts = store.rollouts_for(id).await?;
        unstable = Some((r.rollouts_ended_unstable, rollouts.len()));
        let counts = behaviour_counts(s.task, rollouts.iter().map(|r| (r.success, &r.behaviour.0)));
        if !counts.is_empty() {
            behaviours_svg = Some(
                figures::behaviour_bars_svg("Behaviours of successful rollouts", &counts)
                    .map_err(|e| AppError::Internal(e.to_string()))?,
            );
        }
        let shown = Rollouts::from_parts(s.clone(), r.clone(), rollouts)?;
        if shown.any_trace() {
            overlay_svg = Some(shown.overlay_svg(&state).await?);
            starts_svg = Some(shown.start_map_svg(&state).await?);
        } else {
            let paths = store.avoiding_paths(id).await?;
            if !paths.is_empty() {
                paths_svg = Some(
                    render_avoiding_paths(&paths, "End-effector paths by behaviour")
                        .map_err(|e| AppError::Internal(e.to_string()))?,
                );
            }
        }
        let (b, bad) = rollout_browser(&shown, &q)?;
        browser = Some(b);
        bad_query = bad;
    }
    // The training seeds of the same leaderboard row (one query).
    let seed_lines: Vec<SeedLine> = store
        .sibling_seeds(&s)
        .await?
        .into_iter()
        .map(|o| SeedLine {
            id: o.id,
            seed: o.training_seed,
            status: o.status.to_string(),
            success: o.success_rate.map_or_else(|| "—".into(), fmt_num),
            this: o.id == s.id,
        })
        .collect();
    let policy = match s.policy_kind {
        PolicyKind::Onnx => format!(
            "ONNX file, {} bytes, sha256 {}",
            s.onnx_bytes.unwrap_or(0),
            s.onnx_sha256.as_deref().unwrap_or("?")
        ),
        // Its URL only to its submitter and admins, through the API.
        PolicyKind::Remote => {
            "Remote endpoint (its URL is shown to its submitter and admins: GET /api/v1/submissions/{id} with their token)"
                .to_string()
        }
    };
    let robustness = match s.suite {
        Some(_) => store
            .robustness_summary(id)
            .await?
            .map(|doc| robustness_scores(&doc)),
        None => None,
    };
    let withdrawn = store
        .withdrawal(id)
        .await?
        .map(|w| (fmt_time(w.at), w.by, w.reason));
    let page = render(&SubmissionPage {
        so_far: live_estimate.as_ref().map(so_far),
        cancelled_by: cancelled.map(|c| c.by),
        withdrawn,
        robustness,
        live: matches!(
            s.status,
            SubmissionStatus::Queued | SubmissionStatus::Running
        ),
        // A job not yet started shows its queue position, not "Attempt 0 of 3".
        attempts: if job.attempts > 0 {
            format!("{} of {}", job.attempts, job.max_attempts)
        } else {
            String::new()
        },
        progress_done: p.rollouts_done,
        progress_total: p.rollouts_total,
        queue_position: p.queue_position,
        eta: p.eta_seconds.map(fmt_duration),
        metrics,
        contexts,
        seeds: seed_lines,
        manifest: pretty(&s.manifest_json),
        protocol_manifest,
        sandbox: job.sandbox_json.as_ref().map(pretty).unwrap_or_default(),
        paths_svg,
        overlay_svg,
        starts_svg,
        behaviours_svg,
        browser,
        created: fmt_time(s.created_at),
        policy,
        protocol_name: protocol_str(s.protocol),
        initial_states,
        robot_look,
        mostly_unstable: unstable.is_some_and(|(n, total)| 2 * n > total as i64),
        unstable,
        sorting: matches!(
            s.task,
            TaskId::Sorting2 | TaskId::Sorting4 | TaskId::Sorting6
        ),
        s,
    })?;
    let status = if bad_query {
        StatusCode::BAD_REQUEST
    } else {
        StatusCode::OK
    };
    Ok((status, page).into_response())
}

pub(super) async fn submission_download(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Response, PageError> {
    let v = submission_view(&state, id).await?;
    let body =
        serde_json::to_string_pretty(&v).map_err(|e| AppError::Internal(format!("json: {e}")))?;
    Ok((
        [
            (header::CONTENT_TYPE, "application/json".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"d3il-submission-{id}.json\""),
            ),
        ],
        body,
    )
        .into_response())
}
