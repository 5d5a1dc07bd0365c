//! Server-rendered pages (askama templates in `templates/`, no JavaScript).
//! Templates escape every value; the only unescaped content is SVG that we
//! generate ourselves (plotters escapes the text it draws).

use crate::api::{self, board_for, BoardQuery};
use crate::app::AppState;
use crate::error::{AppError, PageError};
use crate::intake;
use crate::plots::{self, FractionSeries, ParetoPoint};
use crate::store::{BoardRow, MethodRow};
use askama::Template;
use axum::extract::{DefaultBodyLimit, Multipart, Path, Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{Html, IntoResponse, Redirect, Response};
use axum::routing::get;
use axum::Router;
use d3il_protocol::{ObsType, Source, TaskId};
use serde::Deserialize;
use std::collections::{BTreeMap, HashMap};

pub fn router(max_upload: usize) -> Router<AppState> {
    Router::new()
        .route("/", get(home))
        .route("/tasks/{task}", get(leaderboard))
        .route("/tasks/{task}/csv", get(leaderboard_csv))
        .route("/tasks/{task}/data-fraction", get(data_fraction))
        .route("/methods/{name}", get(method_page))
        .route("/submissions/{id}", get(submission_page))
        .route("/submissions/{id}/json", get(submission_download))
        .route(
            "/submit",
            get(submit_form)
                .post(submit_post)
                .layer(DefaultBodyLimit::max(max_upload + (1 << 20))),
        )
        .route("/docs/api", get(api_docs))
        .route("/admin", get(admin_page))
        .route("/static/style.css", get(stylesheet))
        .fallback(not_found)
}

async fn not_found() -> PageError {
    PageError(AppError::NotFound("no such page".into()))
}

fn render<T: Template>(t: &T) -> Result<Html<String>, PageError> {
    t.render()
        .map(Html)
        .map_err(|e| PageError(AppError::Internal(format!("template: {e}"))))
}

#[derive(Template)]
#[template(path = "error.html")]
struct ErrorPage<'a> {
    status: u16,
    reason: &'a str,
    message: String,
    field: Option<String>,
}

pub fn error_page(e: &AppError) -> String {
    let status = e.status();
    ErrorPage {
        status: status.as_u16(),
        reason: status.canonical_reason().unwrap_or("Error"),
        message: e.to_string(),
        field: e.field().map(str::to_string),
    }
    .render()
    .unwrap_or_else(|_| "error".into())
}

// ------------------------------------------------------------------ formatting

pub fn fmt_stat(mean: f64, std: f64) -> String {
    if mean.is_finite() {
        format!("{mean:.3} ± {std:.3}")
    } else {
        "—".into()
    }
}

fn fmt_opt_ms(v: Option<f64>) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.2}"),
        _ => "—".into(),
    }
}

fn fmt_time(t: i64) -> String {
    // Civil date from unix days (Howard Hinnant's algorithm), UTC.
    let days = t.div_euclid(86_400);
    let secs = t.rem_euclid(86_400);
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02} UTC",
        secs / 3600,
        (secs % 3600) / 60
    )
}

fn fmt_duration(s: i64) -> String {
    if s < 90 {
        format!("{s} s")
    } else if s < 5400 {
        format!("{} min", (s + 30) / 60)
    } else {
        format!("{:.1} h", s as f64 / 3600.0)
    }
}

fn url_component(s: &str) -> String {
    url::form_urlencoded::byte_serialize(s.as_bytes())
        .collect::<String>()
        .replace('+', "%20")
}

pub fn method_url(name: &str) -> String {
    format!("/methods/{}", url_component(name))
}

#[derive(Debug, Clone)]
pub struct RowView {
    pub rank: usize,
    pub method: String,
    pub method_url: String,
    pub reported: bool,
    pub protocol: String,
    pub success: String,
    pub entropy: String,
    pub behaviour: String,
    pub seeds: String,
    pub inference: String,
    pub bold_success: bool,
    pub bold_entropy: bool,
    pub submissions: Vec<i64>,
}

fn row_view(rank: usize, r: &BoardRow) -> RowView {
    RowView {
        rank,
        method: r.method.clone(),
        method_url: method_url(&r.method),
        reported: r.source == Source::Reported,
        protocol: r
            .protocol
            .map(crate::store::protocol_str)
            .unwrap_or("")
            .to_string(),
        success: fmt_stat(r.success.mean, r.success.std),
        entropy: fmt_stat(r.entropy.mean, r.entropy.std),
        behaviour: r
            .behaviour_entropy
            .map(|s| fmt_stat(s.mean, s.std))
            .unwrap_or_else(|| "—".into()),
        seeds: r.n_seeds.to_string(),
        inference: fmt_opt_ms(r.inference_ms),
        bold_success: r.bold_success.unwrap_or(false),
        bold_entropy: r.bold_entropy.unwrap_or(false),
        submissions: r.submission_ids.clone(),
    }
}

// ------------------------------------------------------------------------ home

struct TaskCard {
    slug: &'static str,
    title: &'static str,
    reported: usize,
    evaluated: usize,
    best: String,
    has_image: bool,
}

struct SubmissionLine {
    id: i64,
    method: String,
    method_url: String,
    task: String,
    obs: String,
    status: String,
    when: String,
}

#[derive(Template)]
#[template(path = "home.html")]
struct HomePage {
    tasks: Vec<TaskCard>,
    latest: Vec<SubmissionLine>,
    queued: i64,
    running: i64,
}

async fn home(State(state): State<AppState>) -> Result<Html<String>, PageError> {
    let rows = state.store.board_rows().await?;
    let tasks = TaskId::ALL
        .into_iter()
        .map(|t| {
            let mine: Vec<&BoardRow> = rows.iter().filter(|r| r.task == Some(t)).collect();
            // "Best" ranks paper-protocol and reported rows only, not quick smoke runs.
            let best = board_for(&rows, t, ObsType::State)
                .into_iter()
                .filter(|r| r.success.mean.is_finite())
                .filter(|r| r.protocol != Some(d3il_protocol::ProtocolKind::Quick))
                .max_by(|a, b| a.success.mean.total_cmp(&b.success.mean))
                .map(|r| format!("{} ({:.3})", r.method, r.success.mean))
                .unwrap_or_else(|| "—".into());
            TaskCard {
                slug: t.slug(),
                title: t.title(),
                reported: mine.iter().filter(|r| r.source == Source::Reported).count(),
                evaluated: mine
                    .iter()
                    .filter(|r| r.source == Source::Evaluated)
                    .count(),
                best,
                has_image: t.has_image_variant(),
            }
        })
        .collect();
    let latest = state
        .store
        .latest_submissions(10)
        .await?
        .into_iter()
        .map(|s| SubmissionLine {
            id: s.id,
            method_url: method_url(&s.method),
            method: s.method,
            task: s.task,
            obs: s.obs_type,
            status: s.status,
            when: fmt_time(s.created_at),
        })
        .collect();
    let (queued, running) = state.store.queue_counts().await?;
    render(&HomePage {
        tasks,
        latest,
        queued,
        running,
    })
}

// ----------------------------------------------------------------- leaderboard

#[derive(Debug, Deserialize, Default)]
struct SortQuery {
    obs: Option<String>,
    sort: Option<String>,
    dir: Option<String>,
}

pub const SORT_KEYS: [(&str, &str); 7] = [
    ("method", "Method"),
    ("source", "Source"),
    ("success", "Success rate"),
    ("entropy", "Cond. entropy"),
    ("behaviour", "Behaviour entropy"),
    ("seeds", "Seeds"),
    ("inference", "Inference (ms)"),
];

fn sort_rows(rows: &mut [BoardRow], key: &str, desc: bool) {
    let val = |r: &BoardRow| -> f64 {
        let v = match key {
            "entropy" => r.entropy.mean,
            "behaviour" => r.behaviour_entropy.map(|s| s.mean).unwrap_or(f64::NAN),
            "seeds" => r.n_seeds as f64,
            "inference" => r.inference_ms.unwrap_or(f64::NAN),
            _ => r.success.mean,
        };
        // Missing values sort last in either direction.
        if v.is_finite() {
            v
        } else if desc {
            f64::NEG_INFINITY
        } else {
            f64::INFINITY
        }
    };
    match key {
        "method" => rows.sort_by_key(|a| a.method.to_lowercase()),
        "source" => rows.sort_by_key(|r| r.source),
        _ => rows.sort_by(|a, b| val(a).total_cmp(&val(b))),
    }
    if desc {
        rows.reverse();
    }
}

struct Header {
    label: &'static str,
    url: String,
    arrow: &'static str,
}

struct Tab {
    label: &'static str,
    url: String,
    active: bool,
}

struct Section {
    title: String,
    rows: Vec<RowView>,
    svg: String,
}

#[derive(Template)]
#[template(path = "leaderboard.html")]
struct LeaderboardPage {
    title: &'static str,
    slug: &'static str,
    obs: &'static str,
    tabs: Vec<Tab>,
    headers: Vec<Header>,
    sections: Vec<Section>,
    csv_url: String,
    fraction_url: String,
    plot_url: String,
    /// "60 initial states × 8 rollouts (480 in all), at most 400 steps per episode".
    protocol: String,
    /// The protocol is this project's definition (the reference has none).
    protocol_ours: bool,
}

fn obs_tabs(task: TaskId, obs: ObsType, base: &str) -> Vec<Tab> {
    let mut tabs = vec![Tab {
        label: "State",
        url: format!("{base}?obs=state"),
        active: obs == ObsType::State,
    }];
    if task.has_image_variant() {
        tabs.push(Tab {
            label: "Image",
            url: format!("{base}?obs=image"),
            active: obs == ObsType::Image,
        });
    }
    tabs
}

fn obs_of(q: &Option<String>) -> Result<ObsType, AppError> {
    api::parse_obs_query(&BoardQuery {
        obs: q.clone(),
        view: None,
    })
}

/// Splits rows by paper task title, keeping first-seen order (Stacking has
/// three: Stacking-1/2/3).
fn by_title(rows: Vec<BoardRow>) -> Vec<(String, Vec<BoardRow>)> {
    let mut out: Vec<(String, Vec<BoardRow>)> = vec![];
    for r in rows {
        match out.iter_mut().find(|(t, _)| *t == r.task_title) {
            Some((_, v)) => v.push(r),
            None => out.push((r.task_title.clone(), vec![r])),
        }
    }
    out
}

pub fn pareto_points(rows: &[BoardRow]) -> Vec<ParetoPoint> {
    rows.iter()
        .map(|r| ParetoPoint {
            label: match (r.source, r.protocol) {
                (Source::Evaluated, Some(d3il_protocol::ProtocolKind::Quick)) => {
                    format!("{} (quick)", r.method)
                }
                _ => r.method.clone(),
            },
            entropy: r.entropy.mean,
            success: r.success.mean,
            evaluated: r.source == Source::Evaluated,
        })
        .collect()
}

async fn leaderboard(
    State(state): State<AppState>,
    Path(task): Path<String>,
    Query(q): Query<SortQuery>,
) -> Result<Html<String>, PageError> {
    let task = api::parse_task(&task)?;
    let obs = obs_of(&q.obs)?;
    let key = q.sort.as_deref().unwrap_or("success");
    if !SORT_KEYS.iter().any(|(k, _)| *k == key) {
        return Err(AppError::invalid(
            "sort",
            format!(
                "unknown sort column `{key}`; use one of: {}",
                SORT_KEYS.map(|k| k.0).join(", ")
            ),
        )
        .into());
    }
    let desc = match q.dir.as_deref() {
        None => key != "method",
        Some("desc") => true,
        Some("asc") => false,
        Some(d) => {
            return Err(
                AppError::invalid("dir", format!("`dir` must be asc or desc, got `{d}`")).into(),
            )
        }
    };
    let base = format!("/tasks/{}", task.slug());
    let rows = board_for(&state.store.board_rows().await?, task, obs);
    let mut sections = vec![];
    for (title, mut rs) in by_title(rows) {
        let svg = plots::pareto_svg(
            &format!("{title}: success vs diversity"),
            &pareto_points(&rs),
        )
        .map_err(|e| AppError::Internal(e.to_string()))?;
        sort_rows(&mut rs, key, desc);
        sections.push(Section {
            title,
            rows: rs
                .iter()
                .enumerate()
                .map(|(i, r)| row_view(i + 1, r))
                .collect(),
            svg,
        });
    }
    let headers = SORT_KEYS
        .iter()
        .map(|(k, label)| {
            let active = *k == key;
            let next = if active && desc {
                "asc"
            } else if active {
                "desc"
            } else if *k == "method" {
                "asc"
            } else {
                "desc"
            };
            Header {
                label,
                url: format!("{base}?obs={obs}&sort={k}&dir={next}"),
                arrow: if !active {
                    ""
                } else if desc {
                    " ▼"
                } else {
                    " ▲"
                },
            }
        })
        .collect();
    render(&LeaderboardPage {
        title: task.title(),
        slug: task.slug(),
        obs: obs.as_str(),
        tabs: obs_tabs(task, obs, &base),
        headers,
        sections,
        csv_url: format!("{base}/csv?obs={obs}"),
        fraction_url: format!("{base}/data-fraction?obs={obs}"),
        plot_url: format!("/plots/tasks/{}/pareto.svg?obs={obs}", task.slug()),
        protocol: task.paper_protocol().describe(obs),
        protocol_ours: task.paper_protocol().ours,
    })
}

async fn leaderboard_csv(
    State(state): State<AppState>,
    Path(task): Path<String>,
    Query(q): Query<SortQuery>,
) -> Result<Response, PageError> {
    let task = api::parse_task(&task)?;
    let obs = obs_of(&q.obs)?;
    let rows = board_for(&state.store.board_rows().await?, task, obs);
    Ok(api::csv_response(
        &format!("d3il-{}-{}.csv", task.slug(), obs),
        &api::board_csv(&rows),
    ))
}

// --------------------------------------------------------------- data fraction

/// Rows of the data-fraction view: the paper's data-size table and evaluated
/// rows at any fraction (full-data evaluated rows included as the 1.0 point).
pub fn fraction_rows(rows: &[BoardRow], task: TaskId, obs: ObsType) -> Vec<BoardRow> {
    rows.iter()
        .filter(|r| {
            r.task == Some(task)
                && r.obs == obs
                && r.control.is_none()
                && (r.paper_table == "datasize" || r.source == Source::Evaluated)
        })
        .cloned()
        .collect()
}

pub fn fraction_series(rows: &[BoardRow]) -> Vec<FractionSeries> {
    type Points = Vec<(f64, f64, f64)>;
    let mut by: BTreeMap<(String, String), Points> = BTreeMap::new();
    for r in rows {
        let label = match (r.source, r.protocol) {
            (Source::Reported, _) => r.method.clone(),
            // Quick smoke runs get their own line: never mixed with paper-protocol points.
            (Source::Evaluated, Some(d3il_protocol::ProtocolKind::Quick)) => {
                format!("{} (evaluated, quick)", r.method)
            }
            (Source::Evaluated, _) => format!("{} (evaluated)", r.method),
        };
        by.entry((r.task_title.clone(), label)).or_default().push((
            r.data_fraction,
            r.success.mean,
            r.entropy.mean,
        ));
    }
    let multi_title = by
        .keys()
        .map(|k| &k.0)
        .collect::<std::collections::BTreeSet<_>>()
        .len()
        > 1;
    by.into_iter()
        .map(|((title, label), mut points)| {
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            FractionSeries {
                label: if multi_title {
                    format!("{label} [{title}]")
                } else {
                    label
                },
                points,
            }
        })
        .collect()
}

struct FractionRow {
    method: String,
    method_url: String,
    reported: bool,
    cells: Vec<String>,
}

#[derive(Template)]
#[template(path = "data_fraction.html")]
struct FractionPage {
    title: &'static str,
    slug: &'static str,
    tabs: Vec<Tab>,
    fractions: Vec<String>,
    rows: Vec<FractionRow>,
    svg: String,
    csv_url: String,
}

async fn data_fraction(
    State(state): State<AppState>,
    Path(task): Path<String>,
    Query(q): Query<SortQuery>,
) -> Result<Html<String>, PageError> {
    let task = api::parse_task(&task)?;
    let obs = obs_of(&q.obs)?;
    let rows = fraction_rows(&state.store.board_rows().await?, task, obs);
    let mut fracs: Vec<f64> = rows.iter().map(|r| r.data_fraction).collect();
    fracs.sort_by(|a, b| a.total_cmp(b));
    fracs.dedup();
    let mut table: Vec<FractionRow> = vec![];
    for r in &rows {
        let key = (
            r.method.clone(),
            r.source == Source::Reported,
            r.task_title.clone(),
        );
        let i = fracs
            .iter()
            .position(|f| *f == r.data_fraction)
            .unwrap_or(0);
        let mut label = if r.task_title == task.title() {
            key.0.clone()
        } else {
            format!("{} [{}]", key.0, key.2)
        };
        if r.protocol == Some(d3il_protocol::ProtocolKind::Quick) {
            // A quick smoke run is its own row, never a cell of the paper-protocol row.
            label.push_str(" (quick protocol)");
        }
        let row = match table
            .iter_mut()
            .position(|t| t.method == label && t.reported == key.1)
        {
            Some(p) => &mut table[p],
            None => {
                table.push(FractionRow {
                    method: label,
                    method_url: method_url(&r.method),
                    reported: key.1,
                    cells: vec!["—".into(); fracs.len()],
                });
                table
                    .last_mut()
                    .ok_or_else(|| AppError::Internal("empty table".into()))?
            }
        };
        row.cells[i] = format!(
            "{} / {}",
            fmt_stat(r.success.mean, r.success.std),
            fmt_stat(r.entropy.mean, r.entropy.std)
        );
    }
    let svg = plots::data_fraction_svg(
        &format!("{}: performance vs training data", task.title()),
        &fraction_series(&rows),
    )
    .map_err(|e| AppError::Internal(e.to_string()))?;
    render(&FractionPage {
        title: task.title(),
        slug: task.slug(),
        tabs: obs_tabs(task, obs, &format!("/tasks/{}/data-fraction", task.slug())),
        fractions: fracs.iter().map(|f| format!("{f}")).collect(),
        rows: table,
        svg,
        csv_url: format!(
            "/api/v1/leaderboards/{}/csv?obs={obs}&view=data-fraction",
            task.slug()
        ),
    })
}

// ---------------------------------------------------------------------- method

struct MethodResult {
    task: String,
    task_url: String,
    obs: String,
    fraction: String,
    control: String,
    reported: bool,
    protocol: String,
    success: String,
    entropy: String,
    seeds: String,
}

#[derive(Template)]
#[template(path = "method.html")]
struct MethodPage {
    m: MethodRow,
    history: String,
    results: Vec<MethodResult>,
    submissions: Vec<SubmissionLine>,
}

async fn method_page(
    State(state): State<AppState>,
    Path(name): Path<String>,
) -> Result<Html<String>, PageError> {
    let m = state
        .store
        .method_by_name(&name)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("method `{name}` not found")))?;
    let results = state
        .store
        .board_rows()
        .await?
        .into_iter()
        .filter(|r| r.method_id == m.id)
        .map(|r| MethodResult {
            task_url: r
                .task
                .map(|t| format!("/tasks/{}?obs={}", t.slug(), r.obs))
                .unwrap_or_default(),
            task: r.task_title.clone(),
            obs: r.obs.to_string(),
            fraction: format!("{}", r.data_fraction),
            control: r.control.clone().unwrap_or_default(),
            reported: r.source == Source::Reported,
            protocol: r
                .protocol
                .map(crate::store::protocol_str)
                .unwrap_or("")
                .into(),
            success: fmt_stat(r.success.mean, r.success.std),
            entropy: fmt_stat(r.entropy.mean, r.entropy.std),
            seeds: r.n_seeds.to_string(),
        })
        .collect();
    let submissions = state
        .store
        .submissions_of_method(m.id)
        .await?
        .into_iter()
        .map(|s| SubmissionLine {
            id: s.id,
            method_url: method_url(&s.method),
            method: s.method,
            task: s.task,
            obs: s.obs_type,
            status: s.status,
            when: fmt_time(s.created_at),
        })
        .collect();
    render(&MethodPage {
        history: m
            .history
            .map(|h| h.to_string())
            .unwrap_or_else(|| "—".into()),
        m,
        results,
        submissions,
    })
}

// ------------------------------------------------------------------ submission

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
}

#[derive(Template)]
#[template(path = "submission.html")]
struct SubmissionPage {
    s: crate::store::SubmissionRow,
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
    behaviours_svg: Option<String>,
    created: String,
    policy: String,
}

fn parse_id(s: &str) -> Result<i64, AppError> {
    s.parse::<i64>()
        .ok()
        .filter(|i| *i > 0)
        .ok_or_else(|| AppError::NotFound(format!("no submission `{s}`")))
}

fn pretty(json: &str) -> String {
    serde_json::from_str::<serde_json::Value>(json)
        .ok()
        .and_then(|v| serde_json::to_string_pretty(&v).ok())
        .unwrap_or_else(|| json.to_string())
}

/// Successful-rollout counts per behaviour label, most frequent first.
pub fn behaviour_counts(rollouts: &[crate::store::RolloutRow]) -> Vec<(String, usize)> {
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    for r in rollouts.iter().filter(|r| r.success) {
        let v: serde_json::Value =
            serde_json::from_str(&r.behaviour_json).unwrap_or(serde_json::Value::Null);
        *counts.entry(plots::behaviour_label(&v)).or_default() += 1;
    }
    let mut v: Vec<_> = counts.into_iter().collect();
    v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    v
}

async fn submission_page(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Html<String>, PageError> {
    let id = parse_id(&id)?;
    let store = &state.store;
    let s = store.submission(id).await?;
    let job = store.job_for(id).await?;
    let p = api::progress(&state, &job).await?;
    let result = store.result_for(id).await?;
    let mut metrics = vec![];
    let mut contexts = vec![];
    let mut protocol_manifest = String::new();
    let mut paths_svg = None;
    let mut behaviours_svg = None;
    if let Some(r) = &result {
        let ci = |lo: f64, hi: f64| format!("[{lo:.3}, {hi:.3}]");
        metrics = vec![
            MetricLine {
                name: "Success rate",
                value: format!("{:.3}", r.success_rate),
                ci: ci(r.success_ci_low, r.success_ci_high),
            },
            MetricLine {
                name: "Conditional behaviour entropy",
                value: format!("{:.3}", r.conditional_entropy),
                ci: ci(r.conditional_ci_low, r.conditional_ci_high),
            },
            MetricLine {
                name: "Behaviour entropy H(π(β))",
                value: format!("{:.3}", r.behaviour_entropy),
                ci: ci(r.behaviour_ci_low, r.behaviour_ci_high),
            },
            MetricLine {
                name: "Inference time per query (ms)",
                value: format!("{:.2}", r.inference_ms),
                ci: String::new(),
            },
        ];
        let levels = r
            .stacking_levels_json
            .as_deref()
            .and_then(|j| serde_json::from_str::<[d3il_protocol::StackingLevel; 3]>(j).ok());
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
                    metrics.push(MetricLine {
                        name,
                        value: format!("{:.3}", e.value),
                        ci: ci(e.ci_low, e.ci_high),
                    });
                }
            }
        } else if let Some(st) = r
            .stacking_json
            .as_deref()
            .and_then(|j| serde_json::from_str::<[f64; 3]>(j).ok())
        {
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
                    value: format!("{:.3}", st[k]),
                    ci: String::new(),
                });
            }
        }
        let per: Vec<d3il_protocol::ContextResult> =
            serde_json::from_str(&r.per_context_json).unwrap_or_default();
        contexts = per
            .iter()
            .map(|c| ContextLine {
                index: c.context_index,
                success: format!("{:.3}", c.success_rate),
                entropy: format!("{:.3}", c.conditional_entropy),
                behaviours: c
                    .behaviours
                    .iter()
                    .map(|(b, n)| format!("{b}×{n}"))
                    .collect::<Vec<_>>()
                    .join(", "),
            })
            .collect();
        protocol_manifest = pretty(&r.manifest_json);
        let rollouts = store.rollouts_for(id).await?;
        let counts = behaviour_counts(&rollouts);
        if !counts.is_empty() {
            behaviours_svg = Some(
                plots::behaviour_bars_svg("Behaviours of successful rollouts", &counts)
                    .map_err(|e| AppError::Internal(e.to_string()))?,
            );
        }
        let paths = store.avoiding_paths(id).await?;
        if !paths.is_empty() {
            paths_svg = Some(
                plots::paths_svg("End-effector paths by behaviour", &paths)
                    .map_err(|e| AppError::Internal(e.to_string()))?,
            );
        }
    }
    // The other training seeds of the same leaderboard row.
    let seeds = store
        .submissions_of_method(s.method_id)
        .await?
        .into_iter()
        .filter(|o| {
            o.task == s.task
                && o.obs_type == s.obs_type
                && o.data_fraction == s.data_fraction
                && o.protocol == s.protocol
        })
        .collect::<Vec<_>>();
    let mut seed_lines = vec![];
    for o in seeds {
        let success = match store.result_for(o.id).await? {
            Some(r) => format!("{:.3}", r.success_rate),
            None => "—".into(),
        };
        seed_lines.push(SeedLine {
            id: o.id,
            seed: o.training_seed,
            status: o.status,
            success,
            this: o.id == s.id,
        });
    }
    seed_lines.sort_by_key(|l| (l.seed, l.id));
    let policy = match s.policy_kind.as_str() {
        "onnx" => format!(
            "ONNX file, {} bytes, sha256 {}",
            s.onnx_bytes.unwrap_or(0),
            s.onnx_sha256.as_deref().unwrap_or("?")
        ),
        _ => format!(
            "Remote endpoint {}",
            s.endpoint_url.as_deref().unwrap_or("?")
        ),
    };
    render(&SubmissionPage {
        live: s.status == "queued" || s.status == "running",
        attempts: format!("{} of {}", job.attempts, job.max_attempts),
        progress_done: p.rollouts_done,
        progress_total: p.rollouts_total,
        queue_position: p.queue_position,
        eta: p.eta_seconds.map(fmt_duration),
        metrics,
        contexts,
        seeds: seed_lines,
        manifest: pretty(&s.manifest_json),
        protocol_manifest,
        sandbox: job.sandbox_json.as_deref().map(pretty).unwrap_or_default(),
        paths_svg,
        behaviours_svg,
        created: fmt_time(s.created_at),
        policy,
        s,
    })
}

async fn submission_download(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, PageError> {
    let id = parse_id(&id)?;
    let v = api::submission_json(&state, id).await?;
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

// ---------------------------------------------------------------------- submit

#[derive(Template)]
#[template(path = "submit.html")]
struct SubmitPage {
    tasks: Vec<(&'static str, &'static str)>,
    max_upload_mb: usize,
    error: Option<String>,
    error_field: Option<String>,
    /// After an error: the text fields as sent (never the token), so the
    /// form comes back filled in.
    values: HashMap<String, String>,
}

impl SubmitPage {
    /// The value to put back into field `name` ("" when none was sent).
    fn value(&self, name: &str) -> &str {
        self.values.get(name).map(String::as_str).unwrap_or("")
    }

    /// Whether option `option` of select `name` was the one sent (or, when
    /// nothing was sent, is the default).
    fn selected(&self, name: &str, option: &str, default: &str) -> bool {
        match self.values.get(name) {
            Some(v) => v == option,
            None => option == default,
        }
    }
}

async fn submit_form(State(state): State<AppState>) -> Result<Html<String>, PageError> {
    render(&SubmitPage {
        tasks: TaskId::ALL.iter().map(|t| (t.slug(), t.title())).collect(),
        max_upload_mb: state.cfg.max_upload_bytes >> 20,
        error: None,
        error_field: None,
        values: HashMap::new(),
    })
}

/// The HTML form posts the same fields as the API plus `token`; on success it
/// redirects to the submission page, on error it shows the form again with
/// the message naming the field.
async fn submit_post(
    State(state): State<AppState>,
    headers: HeaderMap,
    mp: Result<Multipart, axum::extract::multipart::MultipartRejection>,
) -> Response {
    let mut kept: HashMap<String, String> = HashMap::new();
    let result: Result<i64, AppError> = async {
        let max = state.cfg.max_upload_bytes;
        intake::check_declared_length(&headers, max)?;
        let mp = mp.map_err(|e| AppError::Invalid {
            field: None,
            message: format!("expected a multipart/form-data body: {e}"),
        })?;
        // The token is checked before any file part is read.
        let (raw, who) = intake::read_form_authenticated(mp, max, &state).await?;
        kept = raw.text.clone();
        kept.remove("token");
        let valid = intake::validate(&raw, &state.cfg.limits)?;
        intake::accept(&state, valid, &who).await
    }
    .await;
    match result {
        Ok(id) => Redirect::to(&format!("/submissions/{id}")).into_response(),
        Err(e) => {
            let status = e.status();
            let page = SubmitPage {
                tasks: TaskId::ALL.iter().map(|t| (t.slug(), t.title())).collect(),
                max_upload_mb: state.cfg.max_upload_bytes >> 20,
                error: Some(if kept.is_empty() {
                    e.to_string()
                } else {
                    format!("{e} (your fields are kept below; choose the ONNX file again)")
                }),
                error_field: e.field().map(str::to_string),
                values: kept,
            };
            match page.render() {
                Ok(html) => {
                    let mut resp = (status, Html(html)).into_response();
                    if let AppError::RateLimited { retry_after } = e {
                        if let Ok(v) = header::HeaderValue::from_str(&retry_after.to_string()) {
                            resp.headers_mut().insert(header::RETRY_AFTER, v);
                        }
                    }
                    resp
                }
                Err(_) => PageError(e).into_response(),
            }
        }
    }
}

// ------------------------------------------------------------------- api docs

#[derive(Template)]
#[template(path = "api_docs.html")]
struct ApiDocsPage {
    max_upload_mb: usize,
    rate_limit: u32,
}

async fn api_docs(State(state): State<AppState>) -> Result<Html<String>, PageError> {
    render(&ApiDocsPage {
        max_upload_mb: state.cfg.max_upload_bytes >> 20,
        rate_limit: state.cfg.rate_limit_per_minute,
    })
}

async fn stylesheet(State(state): State<AppState>) -> Response {
    let path = state.cfg.assets_dir.join("static/style.css");
    match tokio::fs::read_to_string(&path).await {
        Ok(css) => ([(header::CONTENT_TYPE, "text/css; charset=utf-8")], css).into_response(),
        Err(e) => {
            tracing::warn!("stylesheet {}: {e}", path.display());
            (StatusCode::NOT_FOUND, "stylesheet missing; check --assets").into_response()
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn civil_time_formatting() {
        assert_eq!(super::fmt_time(0), "1970-01-01 00:00 UTC");
        assert_eq!(super::fmt_time(1_700_000_000), "2023-11-14 22:13 UTC");
    }
}

// ----------------------------------------------------------------------- admin

struct MechanismLine {
    name: String,
    active: bool,
    detail: String,
}

fn mechanism_lines(ms: &[d3il_protocol::SandboxMechanism]) -> Vec<MechanismLine> {
    ms.iter()
        .map(|m| MechanismLine {
            name: m.name.clone(),
            active: m.active,
            detail: m.detail.clone(),
        })
        .collect()
}

#[derive(Template)]
#[template(path = "admin.html")]
struct AdminPage {
    checked_at: String,
    /// Why the check could not run, if it could not.
    check_error: Option<String>,
    /// Mechanisms first, then probes (`probe:...`), as the worker lists them.
    mechanisms: Vec<MechanismLine>,
    missing: Vec<String>,
    breached: Vec<String>,
    last_job: Option<(i64, String)>,
    last_job_mechanisms: Vec<MechanismLine>,
    queued: i64,
    running: i64,
    workers: usize,
    limits: Vec<(&'static str, String)>,
}

/// Operators' view: the sandbox mechanisms in force on this host (what
/// `d3il worker --check-sandbox` reports, including what the kernel lacks),
/// the mechanisms the last finished job ran under, the queue and the limits.
async fn admin_page(State(state): State<AppState>) -> Result<Html<String>, PageError> {
    let check = state.sandbox.get().await;
    let (mechanisms, check_error) = match &check.result {
        Ok(ms) => (mechanism_lines(ms), None),
        Err(e) => (vec![], Some(e.clone())),
    };
    let missing = check
        .missing()
        .iter()
        .filter(|m| !m.name.starts_with("probe:"))
        .map(|m| m.name.clone())
        .collect();
    let breached = check
        .missing()
        .iter()
        .filter(|m| m.name.starts_with("probe:"))
        .map(|m| m.name.clone())
        .collect();
    let (last_job, last_job_mechanisms) = match state.store.latest_sandbox_report().await? {
        Some((sub, at, json)) => {
            let ms: Vec<d3il_protocol::SandboxMechanism> =
                serde_json::from_str(&json).unwrap_or_default();
            (Some((sub, fmt_time(at))), mechanism_lines(&ms))
        }
        None => (None, vec![]),
    };
    let (queued, running) = state.store.queue_counts().await?;
    let l = &state.cfg.limits;
    let limits = vec![
        ("Memory (address space)", bytes_text(l.memory_bytes)),
        ("CPU time", format!("{} s", l.cpu_seconds)),
        ("Wall clock", format!("{} s", l.wall_seconds)),
        ("Open files", l.open_files.to_string()),
        ("File size", bytes_text(l.file_size_bytes)),
        (
            "Private/loopback endpoints",
            if l.allow_private_endpoints {
                "allowed (trusted set-up)".to_string()
            } else {
                "refused".to_string()
            },
        ),
    ];
    render(&AdminPage {
        checked_at: fmt_time(check.checked_at),
        check_error,
        mechanisms,
        missing,
        breached,
        last_job,
        last_job_mechanisms,
        queued,
        running,
        workers: state.cfg.workers,
        limits,
    })
}

fn bytes_text(b: u64) -> String {
    if b == 0 {
        "unlimited".into()
    } else if b.is_multiple_of(1 << 30) {
        format!("{} GiB", b >> 30)
    } else {
        format!("{} MiB", b >> 20)
    }
}
