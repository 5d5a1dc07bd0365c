//! Quotas: per submitter, evaluations started in the last
//! 24 hours and in total, and evaluations queued or running at once, plus
//! a cap on races queued or running. The unit is the evaluation, so that
//! every kind of work is metered by what it costs the workers: a plain
//! submission is one, a robustness suite its level 0 and every level
//! ([`suite_evaluations`]), a race the two evaluations it may
//! run ([`RACE_EVALUATIONS`]). Only accepted work counts (a request refused at
//! admission never gets a row). Admin tokens have none. A submitter's
//! overrides (`d3il token set-quota`, `PUT /api/v1/admin/submitters/{name}/quota`)
//! replace the server's limits (`d3il serve --quota-*`) one by one.

pub use crate::config::QuotaLimits;
use crate::error::AppError;
use crate::state::AppState;
use crate::store::{QuotaUsage, QuotaWork, Submitter, WorkKind, DAY_S};
use d3il_protocol::{ObsType, TaskId};
use serde::Serialize;
use std::path::Path;
use utoipa::ToSchema;

/// Evaluations a race may run: both policies up to the protocol's full size.
pub const RACE_EVALUATIONS: i64 = 2;

/// The evaluations a submission counts for: one, or its suite's level 0 and
/// every level. The one rule for admission and for the usage of stored work.
pub fn submission_evaluations(assets_dir: &Path, task: TaskId, obs: ObsType, suite: bool) -> i64 {
    if !suite {
        return 1;
    }
    suite_evaluations(assets_dir, task, obs).map_or(1, |n| n as i64)
}

/// How many evaluations a suite job of `task` with `obs` observations runs:
/// level 0 and every level of the task's current suite file in
/// `assets_dir/robustness/` (the newest `<task>-v<N>.json`, or
/// `<task>-image-v<N>.json` for image policies). None without a readable
/// suite file.
pub fn suite_evaluations(
    assets_dir: &std::path::Path,
    task: TaskId,
    obs: ObsType,
) -> Option<usize> {
    let prefix = match obs {
        ObsType::State => format!("{}-v", task.slug()),
        ObsType::Image => format!("{}-image-v", task.slug()),
    };
    let newest = std::fs::read_dir(assets_dir.join("robustness"))
        .ok()?
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let v: u32 = name
                .strip_prefix(&prefix)?
                .strip_suffix(".json")?
                .parse()
                .ok()?;
            Some((v, e.path()))
        })
        .max_by_key(|(v, _)| *v)?;
    let file: serde_json::Value = serde_json::from_slice(&std::fs::read(newest.1).ok()?).ok()?;
    let levels: usize = file["axes"]
        .as_array()?
        .iter()
        .map(|a| a["levels"].as_array().map_or(0, Vec::len))
        .sum();
    Some(1 + levels)
}

/// The evaluations a stored unit of work counts for.
pub fn evaluations(assets_dir: &Path, kind: &WorkKind) -> i64 {
    match kind {
        WorkKind::Race => RACE_EVALUATIONS,
        WorkKind::Submission {
            task,
            obs_type,
            suite,
        } => match (task.parse(), obs_type.parse()) {
            (Ok(t), Ok(o)) => submission_evaluations(assets_dir, t, o, *suite),
            _ => 1,
        },
    }
}

/// A submitter's stored work counted in evaluations.
pub fn usage_of(assets_dir: &Path, work: &QuotaWork, t: i64) -> QuotaUsage {
    let mut u = QuotaUsage::default();
    for (at, active, kind) in &work.recent {
        let n = evaluations(assets_dir, kind);
        if *at > t - DAY_S {
            u.last_day += n;
            u.day.push((*at, n));
        }
        if *active {
            u.active += n;
            if *kind == WorkKind::Race {
                u.races += 1;
            }
        }
    }
    u.day.sort_unstable();
    u.total = work
        .totals
        .iter()
        .map(|(kind, n)| evaluations(assets_dir, kind) * n)
        .sum();
    u
}

/// One of the counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
pub struct QuotaCount {
    /// null: no limit.
    pub limit: Option<i64>,
    pub used: i64,
    /// null: no limit.
    pub remaining: Option<i64>,
}

impl QuotaCount {
    fn new(limit: i64, used: i64) -> QuotaCount {
        let limit = (limit > 0).then_some(limit);
        QuotaCount {
            limit,
            used,
            remaining: limit.map(|l| (l - used).max(0)),
        }
    }

    /// Whether work of `cost` evaluations fits.
    fn fits(&self, cost: i64) -> bool {
        self.remaining.is_none_or(|r| r >= cost)
    }
}

/// A submitter's quota as `/whoami` and every submit and race response show it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, ToSchema)]
pub struct QuotaView {
    /// Admin tokens have no quota.
    pub exempt: bool,
    /// Evaluations started in the last 24 hours (a suite counts as its
    /// evaluations, a race as two).
    pub per_day: QuotaCount,
    /// Evaluations started ever.
    pub total: QuotaCount,
    /// Evaluations queued or running.
    pub concurrent: QuotaCount,
    /// Races queued or running (`d3il serve --max-queued-races`).
    pub races: QuotaCount,
    /// Evaluations possible now: the least of the three (null: no limit).
    pub remaining: Option<i64>,
    /// When the daily quota allows the next evaluation, if it allows none
    /// now (unix seconds); null otherwise.
    pub next_submission_at: Option<i64>,
    /// The quota in one sentence (the clients print it).
    pub summary: String,
    #[serde(skip)]
    #[schema(ignore)]
    day: Vec<(i64, i64)>,
}

impl QuotaView {
    /// The view of `usage` under `limits` at time `t`.
    pub fn new(limits: QuotaLimits, usage: QuotaUsage, t: i64) -> QuotaView {
        let per_day = QuotaCount::new(limits.per_day, usage.last_day);
        let total = QuotaCount::new(limits.total, usage.total);
        let concurrent = QuotaCount::new(limits.concurrent, usage.active);
        let races = QuotaCount::new(limits.races, usage.races);
        let remaining = [per_day, total, concurrent]
            .iter()
            .filter_map(|c| c.remaining)
            .min();
        let next_submission_at = (per_day.remaining == Some(0))
            .then(|| freed_at(&usage.day, per_day, 1, t))
            .flatten();
        let part = |c: &QuotaCount, what: &str| match (c.remaining, c.limit) {
            (Some(r), Some(l)) => format!("{r} of {l} {what}"),
            _ => format!("no limit {what}"),
        };
        let summary = if limits == QuotaLimits::NONE {
            "no quota".to_string()
        } else {
            format!(
                "{} left today, {} left in total, {} left at once, {} left",
                part(&per_day, "evaluations"),
                part(&total, "evaluations"),
                part(&concurrent, "evaluations"),
                part(&races, "races at once"),
            )
            .replace("no limit evaluations left today", "no daily limit")
            .replace("no limit evaluations left in total", "no total limit")
            .replace(
                "no limit evaluations left at once",
                "no limit on evaluations at once",
            )
            .replace("no limit races at once left", "no limit on races")
        };
        QuotaView {
            exempt: false,
            per_day,
            total,
            concurrent,
            races,
            remaining,
            next_submission_at,
            summary,
            day: usage.day,
        }
    }

    /// An admin token's (no quota).
    pub fn exempt() -> QuotaView {
        let none = QuotaCount {
            limit: None,
            used: 0,
            remaining: None,
        };
        QuotaView {
            exempt: true,
            per_day: none,
            total: none,
            concurrent: none,
            races: none,
            remaining: None,
            next_submission_at: None,
            summary: "no quota (admin token)".into(),
            day: vec![],
        }
    }

    /// The refusal when `what` (work of `cost` evaluations) does not fit
    /// now, else None. Each refusal names its limit and says when the work
    /// becomes possible, if ever.
    pub fn refusal(&self, t: i64, cost: i64, what: &str) -> Option<AppError> {
        if self.exempt {
            return None;
        }
        let check = "GET /api/v1/whoami shows the quota";
        for (c, name) in [
            (&self.per_day, "daily evaluation quota (--quota-per-day)"),
            (&self.total, "total evaluation quota (--quota-total)"),
            (
                &self.concurrent,
                "quota of evaluations at once (--quota-concurrent)",
            ),
        ] {
            if let Some(l) = c.limit.filter(|&l| cost > l) {
                return Some(AppError::QuotaExceeded {
                    message: format!(
                        "{what} counts {cost} evaluations, more than your {name} of {l}; it is possible only if \
                         the operator raises it (`d3il token set-quota`)"
                    ),
                    retry_after: None,
                    next_at: None,
                });
            }
        }
        if !self.per_day.fits(cost) && self.total.fits(cost) {
            if let (Some(l), Some(at)) = (
                self.per_day.limit,
                freed_at(&self.day, self.per_day, cost, t),
            ) {
                let wait = (at - t).max(1);
                return Some(AppError::QuotaExceeded {
                    message: format!(
                        "daily evaluation quota reached: {} evaluations in the last 24 hours (limit {l}, \
                         --quota-per-day) and {what} counts {cost}; it is possible in {wait} s, at {} UTC ({check})",
                        self.per_day.used,
                        clock(at)
                    ),
                    retry_after: Some(wait as u64),
                    next_at: Some(at),
                });
            }
        }
        if let (Some(l), false) = (self.total.limit, self.total.fits(cost)) {
            return Some(AppError::QuotaExceeded {
                message: format!(
                    "total evaluation quota reached: {} evaluations (limit {l}, --quota-total) and {what} counts \
                     {cost}; no more are possible unless the operator raises it (`d3il token set-quota`)",
                    self.total.used
                ),
                retry_after: None,
                next_at: None,
            });
        }
        if let (Some(l), false) = (self.concurrent.limit, self.concurrent.fits(cost)) {
            return Some(AppError::QuotaExceeded {
                message: format!(
                    "{} evaluations of yours are queued or running (limit {l} at once, --quota-concurrent) and \
                     {what} counts {cost}; it is possible when enough of them finish ({check})",
                    self.concurrent.used
                ),
                retry_after: Some(60),
                next_at: None,
            });
        }
        None
    }

    /// The refusal of one more race when the submitter's races at once are
    /// at their cap, else None.
    pub fn race_refusal(&self) -> Option<AppError> {
        let l = self.races.limit?;
        (self.races.remaining == Some(0)).then(|| AppError::QuotaExceeded {
            message: format!(
                "{} races of yours are queued or running (limit {l} at once, --max-queued-races); another is \
                 possible when one ends or you cancel one (POST /api/v1/races/{{id}}/cancel)",
                self.races.used
            ),
            retry_after: Some(60),
            next_at: None,
        })
    }
}

/// When enough of the day's work (`day`: accepted at, evaluations; oldest
/// first) has left the 24-hour window for `cost` more evaluations to fit
/// `per_day`; None when it fits now or never can.
fn freed_at(day: &[(i64, i64)], per_day: QuotaCount, cost: i64, t: i64) -> Option<i64> {
    let l = per_day.limit?;
    let mut used = per_day.used;
    if used + cost <= l {
        return None;
    }
    for &(at, n) in day {
        used -= n;
        if used + cost <= l {
            return Some((at + DAY_S).max(t));
        }
    }
    None
}

/// `HH:MM:SS` of unix time `t` (UTC).
fn clock(t: i64) -> String {
    let s = t.rem_euclid(86_400);
    format!("{:02}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

/// `who`'s quota now.
pub async fn status(state: &AppState, who: &Submitter) -> Result<QuotaView, AppError> {
    if who.is_admin {
        return Ok(QuotaView::exempt());
    }
    let limits = state
        .cfg
        .quotas
        .with(state.store.quota_overrides(who.id).await?);
    let t = crate::store::now();
    let usage = if limits == QuotaLimits::NONE {
        QuotaUsage::default()
    } else {
        let work = state.store.quota_work(who.id, t).await?;
        usage_of(&state.cfg.assets_dir, &work, t)
    };
    Ok(QuotaView::new(limits, usage, t))
}

/// Refuses (429, naming the limit and when) when `who` may not start
/// `what`, work of `cost` evaluations, now.
pub async fn admit(
    state: &AppState,
    who: &Submitter,
    cost: i64,
    what: &str,
) -> Result<QuotaView, AppError> {
    let q = status(state, who).await?;
    match q.refusal(crate::store::now(), cost, what) {
        Some(e) => Err(e),
        None => Ok(q),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const L: QuotaLimits = QuotaLimits {
        per_day: 3,
        total: 5,
        concurrent: 2,
        races: 1,
    };

    /// Usage of `day` (accepted at, evaluations) in the last 24 hours.
    fn usage(day: &[(i64, i64)], total: i64, active: i64) -> QuotaUsage {
        QuotaUsage {
            last_day: day.iter().map(|d| d.1).sum(),
            total,
            active,
            races: 0,
            day: day.to_vec(),
        }
    }

    #[test]
    fn remaining_is_the_least_of_the_three() {
        let q = QuotaView::new(L, usage(&[(100, 1)], 4, 0), 1000);
        assert_eq!(q.remaining, Some(1));
        assert_eq!(q.next_submission_at, None);
        assert!(q.refusal(1000, 1, "a plain evaluation").is_none());
        assert_eq!(
            q.summary,
            "2 of 3 evaluations left today, 1 of 5 evaluations left in total, 2 of 2 evaluations left at once, \
             1 of 1 races at once left"
        );
    }

    #[test]
    fn a_full_day_says_when_enough_evaluations_leave_the_window() {
        let q = QuotaView::new(L, usage(&[(1000, 1), (1500, 2)], 3, 0), 2000);
        assert_eq!(q.next_submission_at, Some(1000 + DAY_S));
        let e = q.refusal(2000, 1, "a plain evaluation").expect("refused");
        assert_eq!(e.status().as_u16(), 429);
        let m = e.to_string();
        assert!(m.contains(&format!("in {} s", 1000 + DAY_S - 2000)), "{m}");
        assert!(m.contains("at 00:16:40 UTC"), "{m}");
        assert!(m.contains("--quota-per-day"), "{m}");
        // Work of 2 evaluations needs the second entry gone too.
        let e = q.refusal(2000, 2, "a race").expect("refused").to_string();
        assert!(e.contains(&format!("in {} s", 1500 + DAY_S - 2000)), "{e}");
    }

    #[test]
    fn work_is_refused_by_what_it_costs_not_by_its_count() {
        // One evaluation of two at once left: a plain one fits, a race not.
        let q = QuotaView::new(L, usage(&[(10, 1)], 1, 1), 20);
        assert!(q.refusal(20, 1, "a plain evaluation").is_none());
        let race = q
            .refusal(20, RACE_EVALUATIONS, "a race")
            .unwrap()
            .to_string();
        assert!(
            race.contains("limit 2 at once, --quota-concurrent"),
            "{race}"
        );
        assert!(race.contains("a race counts 2"), "{race}");
        // A suite larger than a limit can never run: it says so.
        let suite = q
            .refusal(20, 14, "the robustness suite")
            .unwrap()
            .to_string();
        assert!(
            suite.contains("counts 14 evaluations, more than your daily evaluation quota"),
            "{suite}"
        );
        assert!(suite.contains("set-quota"), "{suite}");
    }

    #[test]
    fn spent_total_and_busy_evaluations_are_refused_with_their_reason() {
        let total = QuotaView::new(L, usage(&[], 5, 0), 10);
        assert!(total
            .refusal(10, 1, "a plain evaluation")
            .unwrap()
            .to_string()
            .contains("total evaluation quota"));
        let busy = QuotaView::new(L, usage(&[(5, 1), (6, 1)], 2, 2), 10);
        assert!(busy
            .refusal(10, 1, "a plain evaluation")
            .unwrap()
            .to_string()
            .contains("when enough of them finish"));
    }

    #[test]
    fn a_suite_counts_its_evaluations_and_a_race_two() {
        let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let suite = WorkKind::Submission {
            task: "aligning".into(),
            obs_type: "state".into(),
            suite: true,
        };
        let plain = WorkKind::Submission {
            task: "aligning".into(),
            obs_type: "state".into(),
            suite: false,
        };
        assert_eq!(evaluations(&assets, &suite), 14);
        assert_eq!(evaluations(&assets, &plain), 1);
        assert_eq!(evaluations(&assets, &WorkKind::Race), 2);
        let work = QuotaWork {
            recent: vec![
                (100, true, suite.clone()),
                (200, true, WorkKind::Race),
                (300, false, plain.clone()),
            ],
            totals: vec![(suite, 1), (WorkKind::Race, 1), (plain, 4)],
        };
        let u = usage_of(&assets, &work, 1000);
        assert_eq!((u.last_day, u.active, u.races, u.total), (17, 16, 1, 20));
        let q = QuotaView::new(L, u, 1000);
        assert_eq!(q.races.remaining, Some(0));
        assert!(q
            .race_refusal()
            .unwrap()
            .to_string()
            .contains("--max-queued-races"));
    }

    #[test]
    fn overrides_replace_limits_one_by_one_and_zero_is_no_limit() {
        let l = L.with(crate::store::QuotaOverrides {
            per_day: Some(0),
            total: None,
            concurrent: Some(7),
        });
        assert_eq!(
            l,
            QuotaLimits {
                per_day: 0,
                total: 5,
                concurrent: 7,
                races: 1,
            }
        );
        let q = QuotaView::new(l, usage(&[(1, 100)], 4, 1), 10);
        assert_eq!(q.per_day.limit, None);
        assert_eq!(q.remaining, Some(1));
        assert!(
            q.summary.starts_with("no daily limit, 1 of 5"),
            "{}",
            q.summary
        );
    }
}
