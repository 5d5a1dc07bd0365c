//! The lists: every submission (filtered by task, method, status and
//! submitter) and every method.

use super::format::{fmt_time, method_url};
use super::render;
use crate::error::PageError;
use crate::http::extract::Query;
use crate::state::AppState;
use crate::views::SubmissionListQuery;
use askama::Template;
use axum::extract::State;
use axum::response::Html;
use d3il_protocol::TaskId;

struct Line {
    id: i64,
    method: String,
    method_url: String,
    submitter: String,
    task: String,
    obs: String,
    seed: i64,
    fraction: String,
    protocol: String,
    status: String,
    when: String,
}

struct Choice {
    value: String,
    selected: bool,
}

#[derive(Template)]
#[template(path = "submissions.html")]
struct SubmissionsPage {
    lines: Vec<Line>,
    tasks: Vec<Choice>,
    statuses: Vec<Choice>,
    method: String,
    submitter: String,
    limit: i64,
}

const LIMIT: i64 = 500;

pub(super) async fn submissions_page(
    State(state): State<AppState>,
    Query(q): Query<SubmissionListQuery>,
) -> Result<Html<String>, PageError> {
    let f = q.filter()?;
    let lines = state
        .store
        .list_submissions(&f, LIMIT)
        .await?
        .into_iter()
        .map(|s| Line {
            id: s.id,
            method_url: method_url(&s.method),
            method: s.method,
            submitter: s.submitter.unwrap_or_else(|| "—".into()),
            task: s.task.to_string(),
            obs: s.obs_type.to_string(),
            seed: s.training_seed,
            fraction: format!("{}", s.data_fraction),
            protocol: crate::leaderboard::protocol_str(s.protocol).into(),
            status: s.status.to_string(),
            when: fmt_time(s.created_at),
        })
        .collect();
    let tasks = TaskId::ALL
        .into_iter()
        .map(|t| Choice {
            value: t.slug().into(),
            selected: f.task == Some(t),
        })
        .collect();
    let statuses = ["queued", "running", "completed", "failed"]
        .into_iter()
        .map(|s| Choice {
            value: s.into(),
            selected: f.status.is_some_and(|st| st.as_str() == s),
        })
        .collect();
    render(&SubmissionsPage {
        lines,
        tasks,
        statuses,
        method: f.method.unwrap_or_default(),
        submitter: f.submitter.unwrap_or_default(),
        limit: LIMIT,
    })
}

struct MethodLine {
    name: String,
    url: String,
    from_paper: bool,
    history: String,
    backbone: String,
    prediction: String,
    diversity: String,
    submissions_url: String,
}

#[derive(Template)]
#[template(path = "methods.html")]
struct MethodsPage {
    methods: Vec<MethodLine>,
}

pub(super) async fn methods_page(State(state): State<AppState>) -> Result<Html<String>, PageError> {
    let dash = |v: Option<String>| v.unwrap_or_else(|| "—".into());
    let methods = state
        .store
        .methods()
        .await?
        .into_iter()
        .map(|m| MethodLine {
            url: method_url(&m.name),
            submissions_url: format!(
                "/submissions?method={}",
                url::form_urlencoded::byte_serialize(m.name.as_bytes()).collect::<String>()
            ),
            from_paper: m.from_paper,
            history: m
                .history
                .map(|h| h.to_string())
                .unwrap_or_else(|| "—".into()),
            backbone: dash(m.backbone),
            prediction: dash(m.prediction),
            diversity: dash(m.diversity),
            name: m.name,
        })
        .collect();
    render(&MethodsPage { methods })
}
