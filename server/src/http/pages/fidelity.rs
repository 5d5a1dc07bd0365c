//! `/fidelity`: the latest fidelity report ([`crate::fidelity`]), and
//! `/fidelity/json`, the report itself.

use super::format::fmt_time;
use super::render;
use crate::error::{AppError, PageError};
use crate::fidelity::{FidelityState, Next};
use crate::state::AppState;
use askama::Template;
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{Html, IntoResponse, Response};
use d3il_protocol::fidelity::{FidelityMode, FidelityReport};

struct EpisodeRow {
    file: String,
    description: String,
    steps: String,
    success: String,
    behaviour: String,
    agrees: bool,
    free_steps: usize,
    free_error: String,
    contact_from: String,
    with_original: String,
    one_ulp: String,
    final_gap: String,
}

struct RateRow {
    who: &'static str,
    successes: String,
    value: String,
    interval: String,
    method: String,
}

struct ContextRow {
    context: usize,
    original: String,
    here: String,
    agrees: bool,
    replay: String,
    replay_gap: String,
    replay_same: &'static str,
}

struct PolicyBlock {
    name: String,
    task: String,
    description: String,
    rates: Vec<RateRow>,
    both_ways: String,
    agreement: String,
    open_loop: String,
    contexts: Vec<ContextRow>,
}

struct FrameRow {
    name: String,
    mean: String,
    off: String,
}

struct DeviationRow {
    what: String,
    source: String,
    effect: String,
}

struct ReportView {
    heading: String,
    episodes_intro: String,
    episodes: Vec<EpisodeRow>,
    closed_intro: String,
    policies: Vec<PolicyBlock>,
    frames_intro: String,
    cameras: Vec<FrameRow>,
    frames: Vec<FrameRow>,
    deviations: Vec<DeviationRow>,
}

#[derive(Template)]
#[template(path = "fidelity.html")]
struct FidelityPage {
    /// `computing`, `failed`, `off` or `ready`.
    status: &'static str,
    message: String,
    report: Option<ReportView>,
    /// Which report is shown (`quick` or `full`) and what comes next.
    mode: &'static str,
    label: String,
    /// Reload while something is being computed.
    refresh: bool,
}

fn steps(s: Option<usize>, remaining: usize) -> String {
    s.map(|n| n.to_string())
        .unwrap_or_else(|| format!("all {remaining}"))
}

fn yes_no(b: bool) -> &'static str {
    if b {
        "yes"
    } else {
        "no"
    }
}

fn view(r: &FidelityReport) -> ReportView {
    let e = &r.episodes;
    let episodes = e
        .episodes
        .iter()
        .map(|x| {
            let (contact_from, with_original, one_ulp, final_gap) = match &x.contact {
                Some(c) => (
                    c.starts_at.to_string(),
                    steps(c.with_original, c.remaining),
                    steps(c.one_ulp, c.remaining),
                    format!("{:.1e}", c.final_object_xy_m),
                ),
                None => ("no contact".into(), "–".into(), "–".into(), "–".into()),
            };
            EpisodeRow {
                file: x.file.clone(),
                description: x.description.clone(),
                steps: format!("{} / {}", x.steps_original, x.steps_here),
                success: format!("{} / {}", x.success_original, x.success_here),
                behaviour: format!("{} / {}", x.behaviour_original, x.behaviour_here),
                agrees: x.success_original == x.success_here
                    && x.behaviour_original == x.behaviour_here
                    && x.steps_original == x.steps_here,
                free_steps: x.free_motion_steps,
                free_error: format!("{:.1e}", x.free_motion_tcp_max_m),
                contact_from,
                with_original,
                one_ulp,
                final_gap,
            }
        })
        .collect();
    let c = &r.closed_loop;
    let policies = c
        .policies
        .iter()
        .map(|p| {
            let rate = |who, x: &d3il_protocol::fidelity::Rate| RateRow {
                who,
                successes: format!("{}/{}", x.successes, x.rollouts),
                value: format!("{:.3}", x.value),
                interval: format!("{:.3}–{:.3}", x.ci_low, x.ci_high),
                method: x.interval.clone(),
            };
            let whole = p.open_loop.iter().filter(|o| o.whole_episode).count();
            PolicyBlock {
                name: p.name.clone(),
                task: p.task.clone(),
                description: p.description.clone(),
                rates: vec![rate("original", &p.original), rate("here", &p.here)],
                both_ways: format!(
                    "Our rate inside the original's interval: {}; the original's inside ours: {}.",
                    yes_no(p.here_inside_original_interval),
                    yes_no(p.original_inside_here_interval)
                ),
                agreement: format!(
                    "Over {} initial states ({} rollouts each here): the original's outcome in {:.1} % of our rollouts, its behaviour in {:.1} %.",
                    p.contexts,
                    p.rollouts_per_context_here,
                    100.0 * p.success_agreement,
                    100.0 * p.behaviour_agreement
                ),
                open_loop: format!(
                    "The original's actions replayed open-loop here: {whole} of {} episodes keep our TCP within {:.0e} m of the original's for the whole episode.",
                    p.open_loop.len(),
                    c.tcp_tolerance_m
                ),
                contexts: p
                    .per_context
                    .iter()
                    .zip(&p.open_loop)
                    .map(|(a, b)| ContextRow {
                        context: a.context,
                        original: format!(
                            "{}, {}, {} steps",
                            if a.original_success { "success" } else { "failure" },
                            a.original_behaviour,
                            a.original_steps
                        ),
                        here: format!(
                            "{}/{} succeed, {}/{} same behaviour, {:.0} steps",
                            a.here_successes,
                            a.here_rollouts,
                            a.here_same_behaviour,
                            a.here_rollouts,
                            a.here_mean_steps
                        ),
                        agrees: (a.here_successes == a.here_rollouts) == a.original_success
                            && (a.here_successes == 0) != a.original_success,
                        replay: format!("{} / {}", b.steps_within, b.steps_original),
                        replay_gap: format!("{:.1e}", b.max_within_m),
                        replay_same: yes_no(b.replay_same_success),
                    })
                    .collect(),
            }
        })
        .collect();
    let f = &r.frames;
    ReportView {
        heading: format!(
            "d3il {}, MuJoCo {}: {} report (closed loop under the {} protocol), finished {}, computed in {:.0} s.",
            r.d3il_version,
            r.mujoco_version,
            r.mode.as_str(),
            c.protocol,
            fmt_time(r.generated_unix),
            r.seconds
        ),
        episodes_intro: format!(
            "Each episode recorded in the original replayed open-loop here from its initial state. Free motion lasts until a reference object has moved {:.0e} m. Two runs are together while every TCP and object position is within {:.0e} m; the contact phase is set against how long our own replay stays together with itself after qpos[0] is changed by one ulp at reset (contact is chaotic).",
            e.contact_motion_m, e.together_m
        ),
        episodes,
        closed_intro: format!(
            "Policies evaluated here under the {} protocol (seed 0) against their rollouts in the original (one per initial state). Numbers agree in distribution; state by state an outcome near a decision boundary can flip with the float32 rounding of the inference engine alone.",
            c.protocol
        ),
        policies,
        frames_intro: format!(
            "Our 96×96 frames right after reset to the original's test contexts (robot drawn with {}) against the original's frames of the same states (original code, Mesa llvmpipe): mean absolute difference over all channels in 1/255, and the share of pixels with a channel more than {}/255 away. For scale, the original's own frames on a GPU differ from its llvmpipe frames by 1.0-1.2/255 (front) and 1.5-3.7/255 (in-hand).",
            f.robot_look, f.off_threshold
        ),
        cameras: f
            .cameras
            .iter()
            .map(|s| FrameRow {
                name: format!("{} ({} frames; largest frame mean {:.3})", s.camera, s.frames, s.max_mean_abs),
                mean: format!("{:.3}", s.mean_abs),
                off: format!("{:.2} %", 100.0 * s.share_off),
            })
            .collect(),
        frames: f
            .frames
            .iter()
            .map(|x| FrameRow {
                name: format!("{} context {} {}", x.task, x.context, x.camera),
                mean: format!("{:.3}", x.mean_abs),
                off: format!("{:.2} %", 100.0 * x.share_off),
            })
            .collect(),
        deviations: r
            .deviations
            .iter()
            .map(|d| DeviationRow {
                what: d.what.clone(),
                source: d.source.clone(),
                effect: d.effect.clone(),
            })
            .collect(),
    }
}

pub(super) async fn fidelity_page(
    State(state): State<AppState>,
) -> Result<Html<String>, PageError> {
    let waiting = |status, message| FidelityPage {
        status,
        message,
        report: None,
        mode: "",
        label: String::new(),
        refresh: status == "computing",
    };
    let page = match state.fidelity.state() {
        FidelityState::Off => waiting("off", "This server does not compute the fidelity report (d3il serve --fidelity off). Run `d3il fidelity` to make it.".into()),
        FidelityState::Computing { since, mode } => waiting(
            "computing",
            format!(
                "The {} fidelity report is being computed for this build (started {}); this page shows it when it is ready.",
                mode.as_str(),
                fmt_time(since)
            ),
        ),
        FidelityState::Failed(e) => waiting(
            "failed",
            format!("The fidelity report could not be computed: {e}"),
        ),
        FidelityState::Ready { report, next } => {
            let quick = report.mode == FidelityMode::Quick;
            let what = if quick {
                "Quick report: the closed-loop policies under the quick protocol (3 initial states, 2 rollouts each); episodes and camera frames as in the full report."
            } else {
                "Full report: the closed-loop policies under the paper protocol."
            };
            let after = match &next {
                Next::Nothing => String::new(),
                Next::Full { since } => format!(
                    " The full report is being computed (started {}) and replaces this one when it is ready.",
                    fmt_time(*since)
                ),
                Next::FullFailed(e) => {
                    format!(" The full report could not be computed: {e}")
                }
            };
            FidelityPage {
                status: "ready",
                message: String::new(),
                mode: report.mode.as_str(),
                label: format!("{what}{after}"),
                refresh: matches!(next, Next::Full { .. }),
                report: Some(view(&report)),
            }
        }
    };
    render(&page)
}

pub(super) async fn fidelity_json(State(state): State<AppState>) -> Result<Response, PageError> {
    match state.fidelity.state() {
        FidelityState::Ready { report, .. } => {
            let body = serde_json::to_string_pretty(&*report)
                .map_err(|e| AppError::Internal(format!("json: {e}")))?;
            Ok(([(header::CONTENT_TYPE, "application/json")], body).into_response())
        }
        _ => Ok((
            StatusCode::SERVICE_UNAVAILABLE,
            [(header::RETRY_AFTER, "60")],
            "the fidelity report is not ready; see /fidelity",
        )
            .into_response()),
    }
}
