//! Submission quotas (issue 42): per submitter, submissions in the last 24
//! hours and in total, and evaluations queued or running at once. Only
//! accepted submissions count (one refused at admission, for a bad file or a
//! failed dry run, never gets a row). Admin tokens have none. A submitter's
//! overrides (`d3il token set-quota`, `PUT /api/v1/admin/submitters/{name}/quota`)
//! replace the server's limits (`d3il serve --quota-*`) one by one.

pub use crate::config::QuotaLimits;
use crate::error::AppError;
use crate::state::AppState;
use crate::store::{QuotaUsage, Submitter, DAY_S};
use serde::Serialize;
use utoipa::ToSchema;

/// One of the three counts.
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
}

/// A submitter's quota as `/whoami` and every submit response show it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, ToSchema)]
pub struct QuotaView {
    /// Admin tokens have no quota.
    pub exempt: bool,
    /// Submissions accepted in the last 24 hours.
    pub per_day: QuotaCount,
    /// Submissions accepted ever.
    pub total: QuotaCount,
    /// Evaluations queued or running.
    pub concurrent: QuotaCount,
    /// Submissions possible now: the least of the three (null: no limit).
    pub remaining: Option<i64>,
    /// When the daily quota allows the next submission, if it allows none
    /// now (unix seconds); null otherwise.
    pub next_submission_at: Option<i64>,
    /// The quota in one sentence (the clients print it).
    pub summary: String,
}

impl QuotaView {
    /// The view of `usage` under `limits` at time `t`.
    pub fn new(limits: QuotaLimits, usage: QuotaUsage, t: i64) -> QuotaView {
        let per_day = QuotaCount::new(limits.per_day, usage.last_day);
        let total = QuotaCount::new(limits.total, usage.total);
        let concurrent = QuotaCount::new(limits.concurrent, usage.active);
        let remaining = [per_day, total, concurrent]
            .iter()
            .filter_map(|c| c.remaining)
            .min();
        let next_submission_at = (per_day.remaining == Some(0))
            .then(|| usage.oldest_in_day.map(|o| (o + DAY_S).max(t)))
            .flatten();
        let part = |c: &QuotaCount, what: &str| match (c.remaining, c.limit) {
            (Some(r), Some(l)) => format!("{r} of {l} {what}"),
            _ => format!("no limit {what}"),
        };
        let summary = if limits == QuotaLimits::NONE {
            "no quota".to_string()
        } else {
            format!(
                "{} left today, {} left in total, {} left at once",
                part(&per_day, "submissions"),
                part(&total, "submissions"),
                part(&concurrent, "evaluations")
            )
            .replace("no limit submissions left today", "no daily limit")
            .replace("no limit submissions left in total", "no total limit")
            .replace(
                "no limit evaluations left at once",
                "no limit on evaluations at once",
            )
        };
        QuotaView {
            exempt: false,
            per_day,
            total,
            concurrent,
            remaining,
            next_submission_at,
            summary,
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
            remaining: None,
            next_submission_at: None,
            summary: "no quota (admin token)".into(),
        }
    }

    /// The refusal when no submission is possible now, else None.
    pub fn refusal(&self, t: i64) -> Option<AppError> {
        if self.remaining != Some(0) {
            return None;
        }
        let check = "GET /api/v1/whoami shows the quota";
        if let (Some(l), Some(at)) = (self.per_day.limit, self.next_submission_at) {
            if self.per_day.remaining == Some(0) && self.total.remaining != Some(0) {
                let wait = (at - t).max(1);
                return Some(AppError::QuotaExceeded {
                    message: format!(
                        "daily submission quota reached: {} submissions in the last 24 hours (limit {l}); \
                         the next submission is possible in {wait} s, at {} UTC ({check})",
                        self.per_day.used,
                        clock(at)
                    ),
                    retry_after: Some(wait as u64),
                    next_at: Some(at),
                });
            }
        }
        if let (Some(l), Some(0)) = (self.total.limit, self.total.remaining) {
            return Some(AppError::QuotaExceeded {
                message: format!(
                    "total submission quota reached: {} submissions (limit {l}); no more are possible \
                     unless the operator raises it (`d3il token set-quota`)",
                    self.total.used
                ),
                retry_after: None,
                next_at: None,
            });
        }
        let l = self.concurrent.limit.unwrap_or(0);
        Some(AppError::QuotaExceeded {
            message: format!(
                "{} of your submissions are queued or running (limit {l} at once); the next submission is \
                 possible when one of them finishes ({check})",
                self.concurrent.used
            ),
            retry_after: Some(60),
            next_at: None,
        })
    }
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
        state.store.quota_usage(who.id, t).await?
    };
    Ok(QuotaView::new(limits, usage, t))
}

/// Refuses (429) when `who` may not submit now.
pub async fn admit(state: &AppState, who: &Submitter) -> Result<(), AppError> {
    let q = status(state, who).await?;
    match q.refusal(crate::store::now()) {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const L: QuotaLimits = QuotaLimits {
        per_day: 3,
        total: 5,
        concurrent: 2,
    };

    fn usage(last_day: i64, total: i64, active: i64, oldest: Option<i64>) -> QuotaUsage {
        QuotaUsage {
            last_day,
            total,
            active,
            oldest_in_day: oldest,
        }
    }

    #[test]
    fn remaining_is_the_least_of_the_three() {
        let q = QuotaView::new(L, usage(1, 4, 0, Some(100)), 1000);
        assert_eq!(q.remaining, Some(1));
        assert_eq!(q.next_submission_at, None);
        assert!(q.refusal(1000).is_none());
        assert_eq!(
            q.summary,
            "2 of 3 submissions left today, 1 of 5 submissions left in total, 2 of 2 evaluations left at once"
        );
    }

    #[test]
    fn a_full_day_says_when_the_oldest_leaves_the_window() {
        let q = QuotaView::new(L, usage(3, 3, 0, Some(1000)), 2000);
        assert_eq!(q.next_submission_at, Some(1000 + DAY_S));
        let e = q.refusal(2000).expect("refused");
        assert_eq!(e.status().as_u16(), 429);
        let m = e.to_string();
        assert!(m.contains(&format!("in {} s", 1000 + DAY_S - 2000)), "{m}");
        assert!(m.contains("at 00:16:40 UTC"), "{m}");
    }

    #[test]
    fn spent_total_and_busy_evaluations_are_refused_with_their_reason() {
        let total = QuotaView::new(L, usage(0, 5, 0, None), 10);
        assert!(total
            .refusal(10)
            .unwrap()
            .to_string()
            .contains("total submission quota"));
        let busy = QuotaView::new(L, usage(2, 2, 2, Some(5)), 10);
        assert!(busy
            .refusal(10)
            .unwrap()
            .to_string()
            .contains("when one of them finishes"));
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
                concurrent: 7
            }
        );
        let q = QuotaView::new(l, usage(100, 4, 1, Some(1)), 10);
        assert_eq!(q.per_day.limit, None);
        assert_eq!(q.remaining, Some(1));
        assert!(
            q.summary.starts_with("no daily limit, 1 of 5"),
            "{}",
            q.summary
        );
    }
}
