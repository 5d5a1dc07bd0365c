//! Quotas and moderation: what a submitter has used of its
//! quota, per-submitter quota overrides, withdrawn submissions, methods
//! marked as baselines, and the audit log of every admin action.

use super::{now, Store, StoreError};

/// A submitter's quota overrides (NULL in the database: the server's
/// default; 0: no limit).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct QuotaOverrides {
    pub per_day: Option<i64>,
    pub total: Option<i64>,
    pub concurrent: Option<i64>,
}

from_row!(QuotaOverrides {
    per_day,
    total,
    concurrent
});

/// What a submitter has used, in evaluations (`crate::quota`
/// counts them): accepted work (refused requests never get a row) in the
/// last 24 hours and ever, and the work still queued or running.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct QuotaUsage {
    pub last_day: i64,
    pub total: i64,
    pub active: i64,
    /// Races queued or running.
    pub races: i64,
    /// The work of the last 24 hours: when each was accepted and its
    /// evaluations (each leaves the window 24 hours later), oldest first.
    pub day: Vec<(i64, i64)>,
}

/// A unit of metered work as stored: a submission (its task, observation
/// type and whether it runs a suite) or a race.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum WorkKind {
    Submission {
        task: String,
        obs_type: String,
        suite: bool,
    },
    Race,
}

/// A submitter's work as [`Store::quota_work`] reads it.
#[derive(Debug, Clone, Default)]
pub struct QuotaWork {
    /// Work accepted in the last 24 hours or still queued or running:
    /// (accepted at, queued or running, kind).
    pub recent: Vec<(i64, bool, WorkKind)>,
    /// All work ever accepted, counted by kind.
    pub totals: Vec<(WorkKind, i64)>,
}

/// Why and when a submission was withdrawn.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, utoipa::ToSchema)]
pub struct Withdrawal {
    /// Unix seconds.
    pub at: i64,
    pub reason: String,
    /// The admin who withdrew it.
    pub by: String,
}

from_row!(Withdrawal { at, reason, by });

/// One admin action.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, utoipa::ToSchema)]
pub struct AuditEntry {
    pub id: i64,
    /// Unix seconds.
    pub at: i64,
    /// The admin token's submitter, or `cli:<user>` for the `d3il` command.
    pub actor: String,
    /// `withdraw`, `reinstate`, `baseline`, `unbaseline`, `revoke_token`, `set_quota`.
    pub action: String,
    /// What it was done to (`submission 12`, `method BC`, `token d3il_ab12…`, `submitter alice`).
    pub target: String,
    pub detail: String,
}

from_row!(AuditEntry {
    id,
    at,
    actor,
    action,
    target,
    detail
});

/// The 24 hours of the per-day quota.
pub const DAY_S: i64 = 86_400;

/// Appends an audit entry at time `$at` inside the caller's transaction
/// (the entry and the action commit together or not at all); its entry.
/// The one insert into `audit_log`: moderation, cancels and race cancels
/// all write through it.
macro_rules! audit_in {
    ($tx:expr, $at:expr, $actor:expr, $action:expr, $target:expr, $detail:expr) => {{
        let e: $crate::store::AuditEntry = sqlx::query_as(
            "INSERT INTO audit_log (at, actor, action, target, detail) VALUES ($1, $2, $3, $4, $5) \
             RETURNING id, at, actor, action, target, detail",
        )
        .bind($at)
        .bind($actor)
        .bind($action)
        .bind($target)
        .bind($detail)
        .fetch_one($tx)
        .await?;
        e
    }};
}
pub(super) use audit_in;

impl Store {
    /// The quota overrides of submitter `id` (all None if it has none).
    pub async fn quota_overrides(&self, submitter_id: i64) -> Result<QuotaOverrides, StoreError> {
        let row: Option<QuotaOverrides> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT quota_per_day AS per_day, quota_total AS total, quota_concurrent AS concurrent \
             FROM submitters WHERE id = $1",
        )
        .bind(submitter_id)
        .fetch_optional(pool)
        .await)?;
        Ok(row.unwrap_or_default())
    }

    /// Sets submitter `name`'s overrides (None: back to the server's
    /// default) and writes the audit entry in the same transaction: the one
    /// way the admin API and `d3il token set-quota` do it. `NotFound` if no
    /// token was ever made for that name.
    pub async fn set_quota(
        &self,
        name: &str,
        q: QuotaOverrides,
        actor: &str,
    ) -> Result<AuditEntry, StoreError> {
        let show = |v: Option<i64>| match v {
            None => "default".to_string(),
            Some(0) => "no limit".to_string(),
            Some(n) => n.to_string(),
        };
        let detail = format!(
            "per day {}, total {}, at once {}",
            show(q.per_day),
            show(q.total),
            show(q.concurrent)
        );
        on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            let n = sqlx::query(
                "UPDATE submitters SET quota_per_day = $1, quota_total = $2, quota_concurrent = $3 WHERE name = $4",
            )
            .bind(q.per_day)
            .bind(q.total)
            .bind(q.concurrent)
            .bind(name)
            .execute(&mut *tx)
            .await?
            .rows_affected();
            if n == 0 {
                return Err(StoreError::NotFound(format!(
                    "a submitter `{name}` (tokens name one: `d3il token create --name {name}`)"
                )));
            }
            let e = audit_in!(&mut *tx, now(), actor, "set_quota", format!("submitter {name}"), &detail);
            tx.commit().await?;
            Ok(e)
        })
    }

    /// Submitter `id`'s submissions and races at time `t`, for the quota.
    pub async fn quota_work(&self, submitter_id: i64, t: i64) -> Result<QuotaWork, StoreError> {
        type Row = (i64, bool, Option<String>, Option<String>, bool);
        let since = t - DAY_S;
        let recent: Vec<Row> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT created_at, status IN ('queued', 'running'), task, obs_type, suite IS NOT NULL \
             FROM submissions WHERE submitter_id = $1 AND (created_at > $2 OR status IN ('queued', 'running')) \
             UNION ALL SELECT created_at, status IN ('queued', 'running'), NULL, NULL, FALSE \
             FROM comparisons WHERE submitter_id = $1 AND (created_at > $2 OR status IN ('queued', 'running')) \
             ORDER BY 1",
        )
        .bind(submitter_id)
        .bind(since)
        .fetch_all(pool)
        .await)?;
        let totals: Vec<(Option<String>, Option<String>, bool, i64)> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT task, obs_type, suite IS NOT NULL, CAST(COUNT(*) AS BIGINT) FROM submissions \
             WHERE submitter_id = $1 GROUP BY task, obs_type, suite IS NOT NULL \
             UNION ALL SELECT NULL, NULL, FALSE, CAST(COUNT(*) AS BIGINT) FROM comparisons WHERE submitter_id = $1",
        )
        .bind(submitter_id)
        .fetch_all(pool)
        .await)?;
        let kind = |task: Option<String>, obs: Option<String>, suite: bool| match (task, obs) {
            (Some(task), Some(obs_type)) => WorkKind::Submission {
                task,
                obs_type,
                suite,
            },
            _ => WorkKind::Race,
        };
        Ok(QuotaWork {
            recent: recent
                .into_iter()
                .map(|(at, active, task, obs, suite)| (at, active, kind(task, obs, suite)))
                .collect(),
            totals: totals
                .into_iter()
                .filter(|r| r.3 > 0)
                .map(|(task, obs, suite, n)| (kind(task, obs, suite), n))
                .collect(),
        })
    }

    /// Withdraws submission `id` (kept, hidden from boards and tables) and
    /// records it in the audit log; withdrawing again replaces the reason.
    pub async fn withdraw_submission(
        &self,
        id: i64,
        reason: &str,
        actor: &str,
    ) -> Result<AuditEntry, StoreError> {
        let t = now();
        on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            let n = sqlx::query(
                "UPDATE submissions SET withdrawn_at = $1, withdrawn_reason = $2, withdrawn_by = $3 WHERE id = $4",
            )
            .bind(t)
            .bind(reason)
            .bind(actor)
            .bind(id)
            .execute(&mut *tx)
            .await?
            .rows_affected();
            if n == 0 {
                return Err(StoreError::NotFound(format!("submission {id}")));
            }
            let e = audit_in!(&mut *tx, now(), actor, "withdraw", format!("submission {id}"), reason);
            tx.commit().await?;
            Ok(e)
        })
    }

    /// Puts a withdrawn submission back on the boards.
    pub async fn reinstate_submission(
        &self,
        id: i64,
        actor: &str,
    ) -> Result<AuditEntry, StoreError> {
        on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            let n = sqlx::query(
                "UPDATE submissions SET withdrawn_at = NULL, withdrawn_reason = NULL, withdrawn_by = NULL WHERE id = $1",
            )
            .bind(id)
            .execute(&mut *tx)
            .await?
            .rows_affected();
            if n == 0 {
                return Err(StoreError::NotFound(format!("submission {id}")));
            }
            let e = audit_in!(&mut *tx, now(), actor, "reinstate", format!("submission {id}"), "");
            tx.commit().await?;
            Ok(e)
        })
    }

    /// Why submission `id` was withdrawn, if it was.
    pub async fn withdrawal(&self, id: i64) -> Result<Option<Withdrawal>, StoreError> {
        let row: Option<(Option<i64>, Option<String>, Option<String>)> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT withdrawn_at, withdrawn_reason, withdrawn_by FROM submissions WHERE id = $1",
        )
        .bind(id)
        .fetch_optional(pool)
        .await)?;
        Ok(match row {
            Some((Some(at), reason, by)) => Some(Withdrawal {
                at,
                reason: reason.unwrap_or_default(),
                by: by.unwrap_or_default(),
            }),
            _ => None,
        })
    }

    /// Marks method `name` as a baseline (or not): its rows say so on the
    /// boards.
    pub async fn set_baseline(
        &self,
        name: &str,
        baseline: bool,
        actor: &str,
    ) -> Result<AuditEntry, StoreError> {
        let action = if baseline { "baseline" } else { "unbaseline" };
        on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            let n = sqlx::query("UPDATE methods SET baseline = $1 WHERE name = $2")
                .bind(baseline)
                .bind(name)
                .execute(&mut *tx)
                .await?
                .rows_affected();
            if n == 0 {
                return Err(StoreError::NotFound(format!("method `{name}`")));
            }
            let e = audit_in!(&mut *tx, now(), actor, action, format!("method {name}"), "");
            tx.commit().await?;
            Ok(e)
        })
    }

    /// Ids of the methods marked as baselines.
    pub async fn baseline_methods(&self) -> Result<Vec<i64>, StoreError> {
        Ok(
            on_db!(&self.db, pool => sqlx::query_scalar("SELECT id FROM methods WHERE baseline = $1 ORDER BY id")
            .bind(true)
            .fetch_all(pool)
            .await)?,
        )
    }

    /// Appends one admin action to the audit log and returns its entry.
    pub async fn audit(
        &self,
        actor: &str,
        action: &str,
        target: &str,
        detail: &str,
    ) -> Result<AuditEntry, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "INSERT INTO audit_log (at, actor, action, target, detail) VALUES ($1, $2, $3, $4, $5) \
             RETURNING id, at, actor, action, target, detail",
        )
        .bind(now())
        .bind(actor)
        .bind(action)
        .bind(target)
        .bind(detail)
        .fetch_one(pool)
        .await)?)
    }

    /// The newest `limit` admin actions, newest first.
    pub async fn audit_log(&self, limit: i64) -> Result<Vec<AuditEntry>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT id, at, actor, action, target, detail FROM audit_log ORDER BY id DESC LIMIT $1",
        )
        .bind(limit)
        .fetch_all(pool)
        .await)?)
    }
}
