//! `/compare?a=ID&b=ID`: two finished submissions side by side. The paired
//! comparison (difference, interval, p-value) is the API's
//! (`comparison::paired`, i.e. `d3il_metrics::compare_parts`, the same as
//! `d3il compare`); per-initial-state success and the behaviour histograms
//! are shown next to each other. The leaderboard's row selection sends
//! `?s=ID&s=ID` (two ticked submissions), read the same way.

use super::format::{fmt_num, method_url};
use super::render;
use crate::comparison::{finished, paired, Finished};
use crate::error::{AppError, PageError};
use crate::leaderboard::{behaviour_counts, protocol_str};
use crate::rollouts::Rollouts;
use crate::state::AppState;
use askama::Template;
use axum::extract::{RawQuery, State};
use axum::response::{IntoResponse, Response};
use d3il_protocol::{Comparison, PairedDifference};
use d3il_tables::board as figures;
use std::collections::BTreeMap;

struct Side {
    id: i64,
    method: String,
    method_url: String,
    task: String,
    obs: String,
    protocol: &'static str,
    seed: i64,
    behaviours_svg: Option<String>,
}

struct DiffLine {
    name: &'static str,
    a: String,
    b: String,
    diff: String,
    ci: String,
    p: String,
    min_detectable: String,
    /// The interval excludes zero.
    clear: bool,
    /// The interval's method and how it relates to the p-value, or why
    /// there is no interval.
    note: String,
}

struct ContextPair {
    index: usize,
    a: String,
    b: String,
    diff: String,
}

struct BehaviourPair {
    label: String,
    a: usize,
    b: usize,
}

/// One side of the rollout shown side by side.
struct RolloutSide {
    outcome: &'static str,
    behaviour: String,
    ending: String,
    page: String,
    /// The video's URL when a trace is stored.
    video: Option<String>,
    note: String,
}

/// The same rollout (same initial state and index) of A and of B.
struct RolloutPair {
    n: usize,
    /// The largest rollout number.
    last: usize,
    /// Why this rollout was picked (when it was not asked for).
    why: String,
    a: RolloutSide,
    b: RolloutSide,
}

struct Shown {
    a: Side,
    b: Side,
    pair: Option<RolloutPair>,
    setting: String,
    diffs: Vec<DiffLine>,
    resamples: usize,
    contexts: Vec<ContextPair>,
    behaviours: Vec<BehaviourPair>,
    /// What else differs between A and B ([`Comparison::caveats`]).
    caveats: Vec<String>,
}

#[derive(Template)]
#[template(path = "compare.html")]
struct ComparePage {
    /// What was typed into the form (kept on an error).
    a_value: String,
    b_value: String,
    error: Option<String>,
    shown: Option<Shown>,
}

/// `+0.250`: a difference with its sign, three decimals (`0.000` unsigned).
fn signed(x: f64) -> String {
    let t = fmt_num(x);
    if x > 0.0 && t != "0.000" {
        format!("+{t}")
    } else {
        t
    }
}

fn p_text(p: f64) -> String {
    if p.is_finite() && p < 0.001 {
        "< 0.001".into()
    } else {
        fmt_num(p)
    }
}

fn diff_line(name: &'static str, d: &PairedDifference) -> DiffLine {
    DiffLine {
        name,
        a: fmt_num(d.a),
        b: fmt_num(d.b),
        diff: signed(d.difference.value),
        ci: match d.difference.interval() {
            Some((lo, hi)) => format!("[{}, {}]", signed(lo), signed(hi)),
            None => "no interval".into(),
        },
        p: p_text(d.p_value),
        min_detectable: fmt_num(d.min_detectable),
        clear: d
            .difference
            .interval()
            .is_some_and(|(lo, hi)| lo > 0.0 || hi < 0.0),
        note: d.interval_note(),
    }
}

/// Parses one submission id typed or sent by a page (`field` names it in the
/// error): this page's query and the "Race them sequentially" form
/// (`race::race_post`). A leading `#`, as the pages show ids, is allowed.
pub(super) fn parse_id(field: &str, v: &str) -> Result<i64, AppError> {
    let digits = v.trim();
    let digits = digits.strip_prefix('#').unwrap_or(digits);
    digits.trim().parse().map_err(|_| {
        AppError::invalid(
            field,
            format!(
                "`{field}` must be a submission id (an integer, the number shown as #N on its page), got `{v}`"
            ),
        )
    })
}

/// The ids to compare from `a`/`b` or from two `s` (the leaderboard's
/// checkboxes); `None` when nothing was asked yet (the empty form).
fn requested(pairs: &[(String, String)]) -> Result<Option<(i64, i64)>, AppError> {
    let get = |k: &str| {
        pairs
            .iter()
            .find(|(n, v)| n == k && !v.trim().is_empty())
            .map(|(_, v)| v.clone())
    };
    let ticked: Vec<&str> = pairs
        .iter()
        .filter(|(n, _)| n == "s")
        .map(|(_, v)| v.as_str())
        .collect();
    match (get("a"), get("b")) {
        (Some(a), Some(b)) => Ok(Some((parse_id("a", &a)?, parse_id("b", &b)?))),
        (Some(_), None) => Err(AppError::invalid(
            "b",
            "submission B is missing: give two submission ids (/compare?a=ID&b=ID)",
        )),
        (None, Some(_)) => Err(AppError::invalid(
            "a",
            "submission A is missing: give two submission ids (/compare?a=ID&b=ID)",
        )),
        (None, None) if ticked.is_empty() => Ok(None),
        (None, None) if ticked.len() == 2 => {
            Ok(Some((parse_id("s", ticked[0])?, parse_id("s", ticked[1])?)))
        }
        (None, None) => Err(AppError::invalid(
            "s",
            format!(
                "select exactly two submissions to compare (you selected {})",
                ticked.len()
            ),
        )),
    }
}

fn side(f: &Finished, svg: Option<String>) -> Side {
    let s = &f.submission;
    Side {
        id: s.id,
        method: s.method.clone(),
        method_url: method_url(&s.method),
        task: s.task.to_string(),
        obs: s.obs_type.to_string(),
        protocol: protocol_str(s.protocol),
        seed: s.training_seed,
        behaviours_svg: svg,
    }
}

fn rollout_side(r: &Rollouts, n: usize) -> Result<RolloutSide, AppError> {
    let item = r.item(r.row(n)?);
    Ok(RolloutSide {
        outcome: if item.success { "success" } else { "failure" },
        behaviour: item.behaviour_label.clone(),
        ending: item.ending_text.clone(),
        page: item.links.page.clone(),
        video: item
            .has_trace
            .then(|| format!("/submissions/{}/rollouts/{n}/video", r.submission.id)),
        note: r.no_trace_note(),
    })
}

/// Rollout `asked` (`?n=`) of A and B side by side, or by default the
/// first where A and B differ in success.
fn rollout_pair(a: &Rollouts, b: &Rollouts, asked: Option<&str>) -> Result<RolloutPair, AppError> {
    let last = a.rows.len().min(b.rows.len()).saturating_sub(1);
    let success = |r: &Rollouts, n: usize| r.row(n).ok().map(|x| x.success);
    let (n, why) = match asked {
        Some(v) => (
            v.trim()
                .parse::<usize>()
                .ok()
                .filter(|n| *n <= last)
                .ok_or_else(|| {
                    AppError::invalid(
                        "n",
                        format!("`n` must be a rollout number from 0 to {last}, got `{v}`"),
                    )
                })?,
            String::new(),
        ),
        None => match (0..=last).find(|n| success(a, *n) != success(b, *n)) {
            Some(n) => (
                n,
                "the first rollout where A and B differ in success".into(),
            ),
            None => (0, "A and B agree in success on every rollout".into()),
        },
    };
    Ok(RolloutPair {
        n,
        last,
        why,
        a: rollout_side(a, n)?,
        b: rollout_side(b, n)?,
    })
}

async fn build(state: &AppState, a: i64, b: i64, n: Option<&str>) -> Result<Shown, AppError> {
    let fa = finished(state, "a", a).await?;
    let fb = finished(state, "b", b).await?;
    let c: Comparison = paired(&fa, &fb)?;
    let by_index = |f: &Finished| -> BTreeMap<usize, f64> {
        f.result
            .per_context_json
            .iter()
            .map(|c| (c.context_index, c.success_rate))
            .collect()
    };
    let (ca, cb) = (by_index(&fa), by_index(&fb));
    let contexts = ca
        .iter()
        .map(|(i, sa)| {
            let sb = cb.get(i).copied().unwrap_or(f64::NAN);
            ContextPair {
                index: *i,
                a: fmt_num(*sa),
                b: fmt_num(sb),
                diff: signed(sa - sb),
            }
        })
        .collect();
    let mut counts: Vec<Vec<(String, usize)>> = vec![];
    let mut svgs = vec![];
    let mut both = vec![];
    for (f, who) in [(&fa, "A"), (&fb, "B")] {
        let rollouts = state.store.rollouts_for(f.submission.id).await?;
        let found = behaviour_counts(
            f.submission.task,
            rollouts.iter().map(|r| (r.success, &r.behaviour.0)),
        );
        svgs.push(if found.is_empty() {
            None
        } else {
            Some(
                figures::behaviour_bars_svg(
                    &format!("{who}: behaviours of successful rollouts"),
                    &found,
                )
                .map_err(|e| AppError::Internal(e.to_string()))?,
            )
        });
        counts.push(found);
        both.push(Rollouts::from_parts(
            f.submission.clone(),
            f.result.clone(),
            rollouts,
        )?);
    }
    let pair = rollout_pair(&both[0], &both[1], n)?;
    let mut labels: Vec<String> = counts.iter().flatten().map(|(l, _)| l.clone()).collect();
    labels.sort();
    labels.dedup();
    let count = |v: &[(String, usize)], l: &str| v.iter().find(|x| x.0 == l).map_or(0, |x| x.1);
    let mut behaviours: Vec<BehaviourPair> = labels
        .into_iter()
        .map(|l| BehaviourPair {
            a: count(&counts[0], &l),
            b: count(&counts[1], &l),
            label: l,
        })
        .collect();
    behaviours.sort_by(|x, y| (y.a + y.b).cmp(&(x.a + x.b)).then(x.label.cmp(&y.label)));
    let mut svgs = svgs.into_iter();
    Ok(Shown {
        setting: format!(
            "{}, {} protocol, {} initial states × {} rollouts, initial states {} (sha256 {})",
            c.task,
            protocol_str(c.protocol),
            c.n_contexts,
            c.rollouts_per_context,
            c.initial_states,
            c.initial_states_sha256
        ),
        diffs: vec![
            diff_line("Success rate", &c.success_rate),
            diff_line("Conditional behaviour entropy", &c.conditional_entropy),
        ],
        resamples: c.resamples,
        contexts,
        behaviours,
        caveats: c.caveats.clone(),
        pair: Some(pair),
        a: side(&fa, svgs.next().flatten()),
        b: side(&fb, svgs.next().flatten()),
    })
}

pub(super) async fn compare_page(
    State(state): State<AppState>,
    RawQuery(q): RawQuery,
) -> Result<Response, PageError> {
    let pairs: Vec<(String, String)> =
        url::form_urlencoded::parse(q.as_deref().unwrap_or("").as_bytes())
            .into_owned()
            .collect();
    let value = |k: &str| {
        pairs
            .iter()
            .find(|(n, _)| n == k)
            .map(|(_, v)| v.clone())
            .unwrap_or_default()
    };
    let outcome = match requested(&pairs) {
        Ok(None) => Ok(None),
        Ok(Some((a, b))) => {
            let n = pairs
                .iter()
                .find(|(k, v)| k == "n" && !v.trim().is_empty())
                .map(|(_, v)| v.as_str());
            build(&state, a, b, n).await.map(|s| Some((a, b, s)))
        }
        Err(e) => Err(e),
    };
    let (status, page) = match outcome {
        Ok(None) => (
            axum::http::StatusCode::OK,
            ComparePage {
                a_value: value("a"),
                b_value: value("b"),
                error: None,
                shown: None,
            },
        ),
        Ok(Some((a, b, shown))) => (
            axum::http::StatusCode::OK,
            ComparePage {
                a_value: a.to_string(),
                b_value: b.to_string(),
                error: None,
                shown: Some(shown),
            },
        ),
        Err(AppError::Internal(m)) => return Err(AppError::Internal(m).into()),
        Err(e) => (
            e.status(),
            ComparePage {
                a_value: value("a"),
                b_value: value("b"),
                error: Some(e.to_string()),
                shown: None,
            },
        ),
    };
    Ok((status, render(&page)?).into_response())
}
