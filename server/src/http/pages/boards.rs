//! The home page, the leaderboards (main and data-fraction views, CSV) and
//! the method pages.

use super::format::{fmt_opt_ms, fmt_stat, fmt_stat_n, fmt_time, method_url};
use super::render;
use crate::board_figures::{fraction_series, pareto_points};
use crate::error::{AppError, PageError};
use crate::http::csv::{board_csv, csv_response};
use crate::http::extract::Query;
use crate::http::extract::{obs_query, Param};
use crate::leaderboard::{
    board_for, by_title, fraction_rows, protocol_str, rank_groups, sort_rows, BoardRow, RankGroup,
    SORT_KEYS,
};
use crate::state::AppState;
use crate::store::MethodRow;
use askama::Template;
use axum::extract::{Path, State};
use axum::response::{Html, Response};
use d3il_protocol::{ObsType, ProtocolKind, Source, TaskId};
use d3il_tables::board as figures;
use serde::Deserialize;

#[derive(Debug, Clone)]
pub struct RowView {
    /// Rank within the row's group; empty for unranked smoke tests.
    pub rank: String,
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
    /// Evaluated rows: "the original D3IL test contexts" or "our sample".
    pub initial_states: String,
    /// Evaluated image rows whose robot was not drawn as the original's: a
    /// badge and its explanation (empty otherwise).
    pub look_badge: &'static str,
    pub look_note: &'static str,
    /// An operator marked the method as a baseline.
    pub baseline: bool,
    /// The zoo's rows: their data source (empty otherwise).
    pub data_source: String,
    /// Zoo rows made by another build than this one: why (empty otherwise).
    pub drift: String,
}

fn row_view(rank: Option<usize>, r: &BoardRow, current: Option<&str>) -> RowView {
    let look = r.robot_look_note();
    RowView {
        data_source: r.data_source.clone().unwrap_or_default(),
        drift: crate::zoo::drift_note(r, current).unwrap_or_default(),
        rank: rank.map(|n| n.to_string()).unwrap_or_default(),
        method: r.method.clone(),
        method_url: method_url(&r.method),
        reported: r.source == Source::Reported,
        protocol: r.protocol.map(protocol_str).unwrap_or("").to_string(),
        success: fmt_stat(r.success, r.n_seeds),
        entropy: fmt_stat(r.entropy, r.n_seeds),
        behaviour: r
            .behaviour_entropy
            .map(|s| fmt_stat(s, r.n_seeds))
            .unwrap_or_else(|| "—".into()),
        seeds: r.n_seeds.to_string(),
        inference: fmt_opt_ms(r.inference_ms),
        bold_success: r.bold_success.unwrap_or(false),
        bold_entropy: r.bold_entropy.unwrap_or(false),
        submissions: r.submission_ids.clone(),
        initial_states: r.initial_states_label.clone().unwrap_or_default(),
        look_badge: look.map_or("", |n| n.badge),
        look_note: look.map_or("", |n| n.text),
        baseline: r.baseline,
    }
}

/// A submission in a short list (home page, method page).
pub(super) struct SubmissionLine {
    pub(super) id: i64,
    pub(super) method: String,
    pub(super) method_url: String,
    pub(super) task: String,
    pub(super) obs: String,
    pub(super) status: String,
    pub(super) when: String,
}

impl From<crate::store::SubmissionRow> for SubmissionLine {
    fn from(s: crate::store::SubmissionRow) -> Self {
        SubmissionLine {
            id: s.id,
            method_url: method_url(&s.method),
            method: s.method,
            task: s.task.to_string(),
            obs: s.obs_type.to_string(),
            status: s.status.to_string(),
            when: fmt_time(s.created_at),
        }
    }
}

// ----------------------------------------------------------------- leaderboard

#[derive(Debug, Deserialize, Default)]
pub(super) struct SortQuery {
    obs: Option<String>,
    sort: Option<String>,
    dir: Option<String>,
}

struct Header {
    label: &'static str,
    url: String,
    arrow: &'static str,
}

pub(super) struct Tab {
    pub(super) label: &'static str,
    pub(super) url: String,
    pub(super) active: bool,
}

/// Rows ranked together ([`RankGroup`]): one table each.
struct Group {
    heading: String,
    /// `evaluated`, `reported` or `smoke` (the table's `data-group`).
    kind: &'static str,
    rows: Vec<RowView>,
}

struct Section {
    title: String,
    /// `id` of the section, linked from the main table's cells.
    anchor: String,
    groups: Vec<Group>,
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
    /// Sorting-2/4/6: the reference's own protocol differed from the paper's.
    sorting: bool,
    /// Some row has submissions: show the "compare the two ticked" form.
    selectable: bool,
}

pub(super) fn obs_tabs(task: TaskId, obs: ObsType, base: &str) -> Vec<Tab> {
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

pub(super) async fn leaderboard(
    State(state): State<AppState>,
    Param(task): Param<TaskId>,
    Query(q): Query<SortQuery>,
) -> Result<Html<String>, PageError> {
    let obs = obs_query(q.obs.as_deref())?;
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
    let current = state.canary.fingerprint();
    let mut sections = vec![];
    for (title, rs) in by_title(rows) {
        let svg = figures::pareto_svg(
            &format!("{title}: success vs diversity"),
            &pareto_points(&rs),
        )
        .map_err(|e| AppError::Internal(e.to_string()))?;
        let groups = rank_groups(rs)
            .into_iter()
            .map(|(g, mut rs)| {
                sort_rows(&mut rs, key, desc);
                Group {
                    heading: g.heading(current.as_deref()),
                    kind: match g {
                        RankGroup::Evaluated(..) => "evaluated",
                        RankGroup::Zoo(..) => "zoo",
                        RankGroup::Reported => "reported",
                        RankGroup::Smoke => "smoke",
                    },
                    rows: rs
                        .iter()
                        .enumerate()
                        .map(|(i, r)| row_view(g.ranked().then_some(i + 1), r, current.as_deref()))
                        .collect(),
                }
            })
            .collect();
        sections.push(Section {
            anchor: crate::leaderboard::section_anchor(&title),
            title,
            groups,
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
    let selectable = sections
        .iter()
        .flat_map(|s| &s.groups)
        .flat_map(|g| &g.rows)
        .any(|r| !r.submissions.is_empty());
    render(&LeaderboardPage {
        selectable,
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
        sorting: matches!(task, TaskId::Sorting2 | TaskId::Sorting4 | TaskId::Sorting6),
    })
}

pub(super) async fn leaderboard_csv(
    State(state): State<AppState>,
    Param(task): Param<TaskId>,
    Query(q): Query<SortQuery>,
) -> Result<Response, PageError> {
    let obs = obs_query(q.obs.as_deref())?;
    let rows = board_for(&state.store.board_rows().await?, task, obs);
    Ok(csv_response(
        &format!("d3il-{}-{}.csv", task.slug(), obs),
        &board_csv(&rows)?,
    ))
}

// --------------------------------------------------------------- data fraction

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

pub(super) async fn data_fraction(
    State(state): State<AppState>,
    Param(task): Param<TaskId>,
    Query(q): Query<SortQuery>,
) -> Result<Html<String>, PageError> {
    let obs = obs_query(q.obs.as_deref())?;
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
        if r.protocol == Some(ProtocolKind::Quick) {
            // A quick smoke run is its own row, never a cell of the paper-protocol row.
            label.push_str(" (quick protocol)");
        }
        if let Some(source) = &r.data_source {
            // The zoo's rows too.
            label.push_str(&format!(" ({source})"));
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
            fmt_stat(r.success, r.n_seeds),
            fmt_stat_n(r.entropy, r.n_seeds)
        );
    }
    let svg = figures::data_fraction_svg(
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
    /// The zoo's rows: their data source, and (zoo rows of another build)
    /// why they may have moved; empty otherwise.
    data_source: String,
    drift: String,
    submissions: Vec<i64>,
}

#[derive(Template)]
#[template(path = "method.html")]
struct MethodPage {
    m: MethodRow,
    history: String,
    results: Vec<MethodResult>,
    submissions: Vec<SubmissionLine>,
}

pub(super) async fn method_page(
    State(state): State<AppState>,
    Path(name): Path<String>,
) -> Result<Html<String>, PageError> {
    let m = state
        .store
        .method_by_name(&name)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("method `{name}` not found")))?;
    let current = state.canary.fingerprint();
    let results = state
        .store
        .board_rows()
        .await?
        .into_iter()
        .filter(|r| r.method_id == m.id)
        .map(|r| MethodResult {
            data_source: r.data_source.clone().unwrap_or_default(),
            drift: crate::zoo::drift_note(&r, current.as_deref()).unwrap_or_default(),
            submissions: if r.data_source.is_some() {
                r.submission_ids.clone()
            } else {
                vec![]
            },
            task_url: r
                .task
                .map(|t| crate::leaderboard::section_url(t, &r.task_title, r.obs))
                .unwrap_or_default(),
            task: r.task_title.clone(),
            obs: r.obs.to_string(),
            fraction: format!("{}", r.data_fraction),
            control: r.control.clone().unwrap_or_default(),
            reported: r.source == Source::Reported,
            protocol: r.protocol.map(protocol_str).unwrap_or("").into(),
            success: fmt_stat(r.success, r.n_seeds),
            entropy: fmt_stat(r.entropy, r.n_seeds),
            seeds: r.n_seeds.to_string(),
        })
        .collect();
    let submissions = state
        .store
        .submissions_of_method(m.id)
        .await?
        .into_iter()
        .map(SubmissionLine::from)
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
