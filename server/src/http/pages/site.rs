//! The home page (the paper's main table on the web), the submit form, the
//! API docs page, the stylesheet and the operators' admin page.

use super::boards::{SubmissionLine, Tab};
use super::format::{fmt_stat, fmt_time, method_url};
use super::render;
use crate::error::{AppError, PageError};
use crate::http::extract::obs_query;
use crate::http::extract::Query;
use crate::intake;
use crate::leaderboard::task_for_title;
use crate::state::AppState;
use askama::Template;
use axum::extract::{Multipart, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{Html, IntoResponse, Redirect, Response};
use d3il_protocol::TaskId;
use d3il_protocol::{ObsType, Source, Stat};
use d3il_tables::{SourceFilter, TableKind, TablesError};
use std::collections::HashMap;

// ------------------------------------------------------------------------ home

/// A task column of the main table, linking to its board.
struct TaskHead {
    title: String,
    url: String,
}

struct MainCell {
    text: String,
    bold: bool,
    url: String,
}

struct MainRow {
    method: String,
    method_url: String,
    /// `reported` or `evaluated`.
    source: &'static str,
    /// † action chunking, ‡ history.
    marks: String,
    /// Control mode and initial-state set, when the row has them.
    note: String,
    cells: Vec<MainCell>,
}

/// Rows of one of the paper's groups (history-free, history-based, methods
/// not in the paper), separated by a heading row.
struct MainSection {
    label: &'static str,
    rows: Vec<MainRow>,
}

struct MainBlock {
    tasks: Vec<TaskHead>,
    sections: Vec<MainSection>,
}

struct TaskCard {
    slug: &'static str,
    title: &'static str,
    has_image: bool,
}

#[derive(Template)]
#[template(path = "home.html")]
struct HomePage {
    obs: &'static str,
    tabs: Vec<Tab>,
    blocks: Vec<MainBlock>,
    caption: String,
    any_evaluated: bool,
    tasks: Vec<TaskCard>,
    latest: Vec<SubmissionLine>,
    queued: i64,
    running: i64,
    /// The drift canary's outcome on this server (`d3il verify`).
    canary: String,
    build: String,
    /// The zoo's boards: data source, then each task with zoo
    /// rows of `obs` policies.
    zoo: Vec<(String, Vec<ZooBoard>)>,
}

/// (task title, board URL, zoo rows) on the home page.
type ZooBoard = (&'static str, String, usize);

#[derive(Debug, serde::Deserialize, Default)]
pub(super) struct HomeQuery {
    obs: Option<String>,
}

fn section_label(section: u8) -> &'static str {
    match section {
        0 => "History-free methods (the paper's first group)",
        1 => "History-based methods ‡ (the paper's second group)",
        _ => "Methods not in the paper",
    }
}

/// The paper's main table (`d3il_tables::build_table`, the same model as
/// `d3il tables --table main`) as page rows: reported and evaluated rows of a
/// method next to each other, every cell linking to its task's board.
fn main_blocks(model: &d3il_tables::TableModel, obs: ObsType) -> Vec<MainBlock> {
    model
        .blocks
        .iter()
        .map(|b| {
            let urls: Vec<String> = b
                .groups
                .iter()
                .map(|g| match task_for_title(&g.task) {
                    Some(t) => crate::leaderboard::section_url(t, &g.task, obs),
                    None => String::new(),
                })
                .collect();
            let mut sections: Vec<MainSection> = vec![];
            for r in &b.rows {
                let mut marks = String::new();
                if r.dagger() {
                    marks.push('†');
                }
                if r.ddagger() {
                    marks.push('‡');
                }
                let mut note: Vec<String> = vec![];
                if let Some(c) = &r.control {
                    note.push(c.clone());
                }
                if let Some(s) = &r.initial_states {
                    note.push(format!("initial states: {s}"));
                }
                if let Some(l) = &r.robot_look {
                    note.push(l.clone());
                }
                let cells = r
                    .values
                    .iter()
                    .zip(&urls)
                    .flat_map(|(vs, url)| {
                        vs.iter().map(move |v| match v {
                            Some(v) => MainCell {
                                text: fmt_stat(
                                    Stat {
                                        mean: v.mean,
                                        std: v.std,
                                    },
                                    v.n_seeds,
                                ),
                                bold: v.bold,
                                url: url.clone(),
                            },
                            None => MainCell {
                                text: "–".into(),
                                bold: false,
                                url: String::new(),
                            },
                        })
                    })
                    .collect();
                let row = MainRow {
                    method: r.method.clone(),
                    method_url: method_url(&r.method),
                    source: match r.source {
                        Source::Reported => "reported",
                        Source::Evaluated => "evaluated",
                    },
                    marks,
                    note: note.join(", "),
                    cells,
                };
                let label = section_label(r.section());
                match sections.last_mut() {
                    Some(s) if s.label == label => s.rows.push(row),
                    _ => sections.push(MainSection {
                        label,
                        rows: vec![row],
                    }),
                }
            }
            MainBlock {
                tasks: b
                    .groups
                    .iter()
                    .zip(urls)
                    .map(|(g, url)| TaskHead {
                        title: g.task.clone(),
                        url,
                    })
                    .collect(),
                sections,
            }
        })
        .collect()
}

/// `/`: the paper's main table (methods × tasks, success rate and
/// conditional entropy) with our evaluated rows next to the reported ones,
/// state/image tabs (`?obs=`), then the tasks and the latest submissions.
pub(super) async fn home(
    State(state): State<AppState>,
    Query(q): Query<HomeQuery>,
) -> Result<Html<String>, PageError> {
    let obs = obs_query(q.obs.as_deref())?;
    let current = state.canary.fingerprint();
    let cells = state.store.result_cells(current.as_deref()).await?;
    let infos = state.store.method_infos().await?;
    let (blocks, caption, any_evaluated) =
        match d3il_tables::build_table(&cells, TableKind::Main, obs, SourceFilter::Both, &infos) {
            Ok(model) => (
                main_blocks(&model, obs),
                d3il_tables::caption_text(&model),
                !model.facts.evaluated_seeds.is_empty(),
            ),
            Err(TablesError::NoCells { .. }) => (vec![], String::new(), false),
            Err(e) => return Err(AppError::Internal(e.to_string()).into()),
        };
    let tabs = [ObsType::State, ObsType::Image]
        .into_iter()
        .map(|o| Tab {
            label: match o {
                ObsType::State => "State",
                ObsType::Image => "Image",
            },
            url: format!("/?obs={o}"),
            active: o == obs,
        })
        .collect();
    let tasks = TaskId::ALL
        .into_iter()
        .map(|t| TaskCard {
            slug: t.slug(),
            title: t.title(),
            has_image: t.has_image_variant(),
        })
        .collect();
    let latest = state
        .store
        .latest_submissions(10)
        .await?
        .into_iter()
        .map(SubmissionLine::from)
        .collect();
    let (queued, running) = state.store.submission_counts().await?;
    // Not in the paper's table (they are not its numbers): where they are.
    let mut zoo: Vec<(String, Vec<ZooBoard>)> = vec![];
    for r in state.store.board_rows().await? {
        let (Some(source), Some(task)) = (r.data_source, r.task) else {
            continue;
        };
        if r.obs != obs {
            continue;
        }
        let i = match zoo.iter().position(|(s, _)| *s == source) {
            Some(i) => i,
            None => {
                zoo.push((source, vec![]));
                zoo.len() - 1
            }
        };
        let tasks = &mut zoo[i].1;
        match tasks.iter_mut().find(|t| t.0 == task.title()) {
            Some(t) => t.2 += 1,
            None => tasks.push((task.title(), format!("/tasks/{}?obs={obs}", task.slug()), 1)),
        }
    }
    let order = |title: &str| TaskId::ALL.iter().position(|t| t.title() == title);
    for (_, tasks) in &mut zoo {
        tasks.sort_by_key(|t| order(t.0));
    }
    render(&HomePage {
        zoo,
        obs: obs.as_str(),
        tabs,
        blocks,
        caption,
        any_evaluated,
        tasks,
        latest,
        queued,
        running,
        canary: state.canary.state().summary(),
        build: format!(
            "evaluator {} (commit {})",
            env!("CARGO_PKG_VERSION"),
            state.canary.build().git_commit
        ),
    })
}

// ---------------------------------------------------------------- submit form

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

pub(super) async fn submit_form(State(state): State<AppState>) -> Result<Html<String>, PageError> {
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
pub(super) async fn submit_post(
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
        let mut raw = intake::RawSubmission::default();
        let read = intake::read_multipart(mp, &state, intake::Caller::FormToken, &mut raw).await;
        kept = raw.text.clone();
        kept.remove("token");
        let who = read?;
        let valid = intake::validate(raw, &state.cfg.limits)?;
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
                    if let AppError::RateLimited { retry_after, .. } = e {
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

pub(super) async fn api_docs(State(state): State<AppState>) -> Result<Html<String>, PageError> {
    render(&ApiDocsPage {
        max_upload_mb: state.cfg.max_upload_bytes >> 20,
        rate_limit: state.cfg.rate_limit_per_minute,
    })
}

pub(super) async fn stylesheet(State(state): State<AppState>) -> Response {
    let path = state.cfg.assets_dir.join("static/style.css");
    match tokio::fs::read_to_string(&path).await {
        Ok(css) => ([(header::CONTENT_TYPE, "text/css; charset=utf-8")], css).into_response(),
        Err(e) => {
            tracing::warn!("stylesheet {}: {e}", path.display());
            (StatusCode::NOT_FOUND, "stylesheet missing; check --assets").into_response()
        }
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
    server_limits: Vec<(&'static str, String)>,
    /// The newest admin actions, with their time shown.
    audit: Vec<(String, crate::store::AuditEntry)>,
    /// Withdrawn submissions (the public lists leave them out), with the
    /// time they were withdrawn.
    withdrawn: Vec<(String, crate::store::WithdrawnSubmission)>,
}

/// Operators' view: the sandbox mechanisms in force on this host (what
/// `d3il worker --check-sandbox` reports, including what the kernel lacks),
/// the mechanisms the last finished job ran under, the queue and the limits.
/// Only for admin tokens (it shows host paths and the set-up).
pub(super) async fn admin_page(
    _admin: Result<crate::auth::Admin, AppError>,
    State(state): State<AppState>,
) -> Result<Html<String>, PageError> {
    let _admin = _admin?;
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
        Some((sub, at, ms)) => (Some((sub, fmt_time(at))), mechanism_lines(&ms)),
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
                "refused (start with --allow-private-endpoints to allow them)".to_string()
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
        server_limits: server_limits(&state.cfg),
        audit: state
            .store
            .audit_log(200)
            .await?
            .into_iter()
            .map(|e| (fmt_time(e.at), e))
            .collect(),
        withdrawn: state
            .store
            .withdrawn_submissions(200)
            .await?
            .into_iter()
            .map(|w| (fmt_time(w.withdrawal.at), w))
            .collect(),
    })
}

/// The connection, upload, rate and attempt limits `d3il serve` was started
/// with, each named with its flag.
fn server_limits(c: &crate::config::ServerConfig) -> Vec<(&'static str, String)> {
    let per_min = |n: u32| {
        if n == u32::MAX {
            "unlimited".to_string()
        } else {
            format!("{n} per minute")
        }
    };
    // Quotas: 0 is no limit; admin tokens have none.
    let count = |n: i64| {
        if n == 0 {
            "unlimited".to_string()
        } else {
            n.to_string()
        }
    };
    vec![
        (
            "Upload size (--max-upload-mb)",
            bytes_text(c.max_upload_bytes as u64),
        ),
        (
            "Disk per submitter (--max-disk-mb-per-submitter)",
            bytes_text(c.max_disk_bytes_per_submitter.unwrap_or(0)),
        ),
        (
            "Concurrent uploads (--max-concurrent-uploads)",
            c.max_concurrent_uploads.to_string(),
        ),
        (
            "Requests per token (--rate-limit)",
            per_min(c.rate_limit_per_minute),
        ),
        (
            "Requests without a token per address (--anonymous-rate-limit)",
            per_min(c.anonymous_rate_limit_per_minute),
        ),
        (
            "Failed token checks per address (--failed-auth-limit)",
            per_min(c.failed_auth_per_minute),
        ),
        (
            "Header-read and idle timeout (--header-timeout)",
            format!("{} s", c.connections.header_read_timeout.as_secs()),
        ),
        (
            "Open connections (--max-connections)",
            c.connections.max_connections.to_string(),
        ),
        (
            "Open connections per address (--max-connections-per-client)",
            c.connections.max_connections_per_client.to_string(),
        ),
        (
            "Trusted proxies (--trusted-proxy)",
            if c.connections.trusted_proxies.is_empty() {
                "none: X-Forwarded-For is ignored, the peer is the client".to_string()
            } else {
                format!(
                    "{}: their X-Forwarded-For names the client",
                    c.connections.trusted_proxies.describe().join(", ")
                )
            },
        ),
        (
            "Attempts per job (--max-attempts)",
            c.max_attempts.to_string(),
        ),
        (
            "Submissions per submitter in 24 hours (--quota-per-day)",
            count(c.quotas.per_day),
        ),
        (
            "Submissions per submitter in total (--quota-total)",
            count(c.quotas.total),
        ),
        (
            "Evaluations per submitter at once (--quota-concurrent)",
            count(c.quotas.concurrent),
        ),
        (
            "Worker slots (--workers; plus one for quick runs, shared with submission dry-runs)",
            c.workers.to_string(),
        ),
    ]
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
