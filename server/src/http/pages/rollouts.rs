//! What a policy did, as pages: the submission page's failure
//! browser (rollouts filtered by outcome, behaviour and initial state with a
//! plain GET form and links, no script), and a rollout's page: its video,
//! the top-down picture, the per-step plots, how it ended and its record.

use super::format::method_url;
use super::render;
use crate::error::{AppError, PageError};
use crate::http::extract::RolloutParam;
use crate::http::media::serve_video;
use crate::rollouts::{Outcome, RolloutFilter, RolloutList, RolloutQuery, Rollouts};
use crate::state::AppState;
use askama::Template;
use axum::extract::State;
use axum::http::HeaderMap;
use axum::response::{Html, Response};

/// One choice of a filter's select.
pub(super) struct Choice {
    pub value: String,
    pub label: String,
    pub selected: bool,
}

/// One rollout line of the browser.
pub(super) struct RolloutLine {
    pub number: usize,
    pub page: String,
    pub context: usize,
    pub index: usize,
    pub outcome: &'static str,
    pub behaviour: String,
    pub steps: i64,
    pub ending: String,
}

/// The failure browser on the submission page.
pub(super) struct Browser {
    pub outcomes: Vec<Choice>,
    pub behaviours: Vec<Choice>,
    /// What the initial-state field holds.
    pub context: String,
    /// A filter value that names nothing (the page says what is allowed).
    pub error: Option<String>,
    pub total: usize,
    pub all: usize,
    pub page: usize,
    pub pages: usize,
    pub rows: Vec<RolloutLine>,
    /// Links to the previous and next page, filters kept.
    pub prev: Option<String>,
    pub next: Option<String>,
    /// Set when no rollout has a trace (results stored before them).
    pub traces_note: Option<String>,
}

/// The query string of a list with `f`'s filters on `page`.
fn list_query(f: &RolloutFilter, page: usize) -> String {
    let mut q = url::form_urlencoded::Serializer::new(String::new());
    if let Some(o) = f.outcome {
        q.append_pair("outcome", o.as_str());
    }
    if let Some(b) = &f.behaviour {
        q.append_pair("behaviour", b);
    }
    if let Some(c) = f.context {
        q.append_pair("context", &c.to_string());
    }
    if page > 1 {
        q.append_pair("page", &page.to_string());
    }
    q.finish()
}

/// The failure browser of submission `r` for query `q`; a bad value shows
/// the whole list with the message (and the page answers 400).
pub(super) fn browser(r: &Rollouts, q: &RolloutQuery) -> Result<(Browser, bool), AppError> {
    let (filter, error) = match r.filter(q) {
        Ok(f) => (f, None),
        Err(e) => (r.filter(&RolloutQuery::default())?, Some(e.to_string())),
    };
    let (list, error): (RolloutList, Option<String>) = match r.list(&filter) {
        Ok(l) => (l, error),
        Err(e) => {
            let first = RolloutFilter {
                page: 1,
                ..filter.clone()
            };
            (r.list(&first)?, Some(e.to_string()))
        }
    };
    let id = r.submission.id;
    let link = |page: usize| {
        let q = list_query(&filter, page);
        format!("/submissions/{id}?{q}#rollouts")
    };
    let counts = &list.outcomes;
    let b = Browser {
        outcomes: Outcome::ALL
            .iter()
            .map(|o| Choice {
                value: o.as_str().into(),
                label: format!(
                    "{} ({})",
                    o.label(),
                    counts
                        .iter()
                        .find(|c| c.outcome == o.as_str())
                        .map_or(0, |c| c.count)
                ),
                selected: filter.outcome == Some(*o),
            })
            .collect(),
        behaviours: list
            .behaviours
            .iter()
            .map(|l| Choice {
                value: l.clone(),
                label: l.clone(),
                selected: filter.behaviour.as_ref() == Some(l),
            })
            .collect(),
        context: filter.context.map(|c| c.to_string()).unwrap_or_default(),
        total: list.total,
        all: list.all,
        page: list.page,
        pages: list.pages,
        prev: (list.page > 1).then(|| link(list.page - 1)),
        next: (list.page < list.pages).then(|| link(list.page + 1)),
        rows: list
            .items
            .iter()
            .map(|i| RolloutLine {
                number: i.number,
                page: i.links.page.clone(),
                context: i.context,
                index: i.rollout,
                outcome: if i.success { "success" } else { "failure" },
                behaviour: i.behaviour_label.clone(),
                steps: i.steps,
                ending: i
                    .ending
                    .map_or_else(|| "not recorded".to_string(), |e| e.describe().to_string()),
            })
            .collect(),
        traces_note: list.traces_note.clone(),
        error,
    };
    let bad = b.error.is_some();
    Ok((b, bad))
}

#[derive(Template)]
#[template(path = "rollout.html")]
struct RolloutPage {
    id: i64,
    n: usize,
    method: String,
    method_url: String,
    task: String,
    context: usize,
    index: usize,
    per_context: usize,
    success: bool,
    behaviour: String,
    steps: i64,
    seconds: String,
    ending: String,
    failure: Option<(usize, String)>,
    prev: Option<usize>,
    next: Option<usize>,
    /// A trace is stored: video and pictures.
    traced: bool,
    top_down: String,
    step_plots: String,
    /// Why there is no video or picture.
    note: String,
}

/// `/submissions/{id}/rollouts/{n}`.
pub(super) async fn rollout_page(
    State(state): State<AppState>,
    RolloutParam(id, n): RolloutParam,
) -> Result<Html<String>, PageError> {
    let r = Rollouts::load(&state, id).await?;
    let row = r.row(n)?;
    let item = r.item(row);
    let traced = item.has_trace;
    let (top_down, step_plots) = if traced {
        (
            r.top_down_svg(&state, n).await?,
            r.step_plots_svg(&state, n).await?,
        )
    } else {
        (String::new(), String::new())
    };
    let s = &r.submission;
    render(&RolloutPage {
        id,
        n,
        method: s.method.clone(),
        method_url: method_url(&s.method),
        task: s.task.to_string(),
        context: item.context,
        index: item.rollout,
        per_context: r.per_context(),
        success: item.success,
        behaviour: item.behaviour_label.clone(),
        steps: item.steps,
        seconds: format!("{:.2}", item.steps as f64 * s.task.step_seconds()),
        ending: item.ending_text.clone(),
        failure: item.failure.as_ref().map(|f| (f.step, f.message.clone())),
        prev: n.checked_sub(1),
        next: (n + 1 < r.rows.len()).then_some(n + 1),
        traced,
        top_down,
        step_plots,
        note: r.no_trace_note(),
    })
}

/// `/submissions/{id}/rollouts/{n}/video`: the rollout page's video; when it
/// cannot be made, an error page that says why (the API's twin answers JSON).
pub(super) async fn rollout_video(
    State(state): State<AppState>,
    RolloutParam(id, n): RolloutParam,
    headers: HeaderMap,
) -> Result<Response, PageError> {
    let r = Rollouts::load(&state, id).await?;
    let path = r.video(&state, n).await?;
    Ok(serve_video(&path, &headers).await?)
}
