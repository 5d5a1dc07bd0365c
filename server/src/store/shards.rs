//! The shards of a sharded job: each finished shard's part is kept with its
//! job row, and the last one to finish merges them all into the
//! submission's result, in the same transaction. A plain evaluation's parts
//! merge with `d3il_metrics::shard::merge` (as `d3il merge`); a robustness
//! submission's with `d3il_metrics::suite_shard::merge_suite`
//! (as `d3il merge` of suite parts): level 0 becomes the plain result and the
//! document goes to `robustness_results`, as an unsharded suite job stores
//! them.

use super::types::JobState;
use super::{now, to_json, Store, StoreError};
use d3il_metrics::suite_shard::{merge_suite, SuiteLevels};
use d3il_protocol::robustness::{RobustnessPart, RobustnessResult};
use d3il_protocol::shard::EvalPart;
use d3il_protocol::{EvalResult, SandboxMechanism};

/// The part one shard answered with.
#[derive(Debug, Clone, Copy)]
pub enum ShardPart<'a> {
    /// A plain evaluation's shard.
    Plain(&'a EvalPart),
    /// A robustness suite's shard: level 0 and every level on its states.
    Suite(&'a RobustnessPart),
}

impl ShardPart<'_> {
    /// Rollouts recorded by the shard (over every level of a suite).
    fn rollouts(self) -> usize {
        match self {
            ShardPart::Plain(p) => p.rollouts.len(),
            ShardPart::Suite(p) => std::iter::once(&p.control)
                .chain(&p.levels)
                .map(|l| l.rollouts.len())
                .sum(),
        }
    }

    fn json(self) -> String {
        match self {
            ShardPart::Plain(p) => to_json(p),
            ShardPart::Suite(p) => to_json(p),
        }
    }
}

/// The stored parts of a submission's shards, decoded.
enum Parts {
    Plain(Vec<(String, EvalPart)>),
    Suite(Vec<(String, RobustnessPart)>),
}

impl Parts {
    /// Decodes the parts (`(shard index, part JSON)`, in shard order) of a
    /// suite job when `suite`, else of a plain one.
    fn decode(
        submission_id: i64,
        rows: Vec<(i64, Option<String>)>,
        suite: bool,
    ) -> Result<Parts, StoreError> {
        fn each<T: serde::de::DeserializeOwned>(
            submission_id: i64,
            rows: Vec<(i64, Option<String>)>,
        ) -> Result<Vec<(String, T)>, StoreError> {
            rows.into_iter()
                .map(|(index, json)| {
                    let part =
                        serde_json::from_str(json.as_deref().unwrap_or("")).map_err(|e| {
                            StoreError::Corrupt(format!(
                                "shard {} of submission {submission_id}: {e}",
                                index + 1
                            ))
                        })?;
                    Ok((format!("shard {}", index + 1), part))
                })
                .collect()
        }
        Ok(if suite {
            Parts::Suite(each(submission_id, rows)?)
        } else {
            Parts::Plain(each(submission_id, rows)?)
        })
    }

    /// The merged result, and the robustness document of a suite job; the
    /// error is the message the failed submission shows.
    fn merge(self) -> Result<(EvalResult, Option<RobustnessResult>), String> {
        match self {
            Parts::Plain(parts) => d3il_metrics::shard::merge(parts)
                .map(|r| (r, None))
                .map_err(|e| e.to_string()),
            Parts::Suite(parts) => {
                // The worker checked the suite file's sha256; the levels
                // come from the parts, and the merge checks that every
                // shard ran the same ones.
                let levels = match parts.first() {
                    Some((label, first)) => {
                        SuiteLevels::of_part(label, first).map_err(|e| e.to_string())?
                    }
                    None => return Err("no shard left a part".into()),
                };
                let doc = merge_suite(parts, &levels).map_err(|e| e.to_string())?;
                Ok((doc.control.clone(), Some(doc)))
            }
        }
    }
}

impl Store {
    /// Stores the part of one shard of a plain evaluation, run by `owner`
    /// ([`Store::complete_any_shard`]).
    pub async fn complete_shard(
        &self,
        job_id: i64,
        owner: &str,
        part: &EvalPart,
        mechanisms: &[SandboxMechanism],
    ) -> Result<bool, StoreError> {
        self.complete_any_shard(job_id, owner, ShardPart::Plain(part), mechanisms)
            .await
    }

    /// Stores the part of one shard of a robustness submission, run by
    /// `owner` ([`Store::complete_any_shard`]).
    pub async fn complete_suite_shard(
        &self,
        job_id: i64,
        owner: &str,
        part: &RobustnessPart,
        mechanisms: &[SandboxMechanism],
    ) -> Result<bool, StoreError> {
        self.complete_any_shard(job_id, owner, ShardPart::Suite(part), mechanisms)
            .await
    }

    /// Stores the part of one shard, run by `owner`. When it is the last
    /// shard of its submission, the parts are merged (the same as `d3il
    /// merge`) and the result stored, with the robustness document of a
    /// suite job: returns whether that happened. A slot that no longer
    /// holds the lease changes nothing ([`StoreError::LeaseLost`]; the part
    /// another slot ran, or will run, is the same bit for bit).
    pub async fn complete_any_shard(
        &self,
        job_id: i64,
        owner: &str,
        part: ShardPart<'_>,
        mechanisms: &[SandboxMechanism],
    ) -> Result<bool, StoreError> {
        let t = now();
        let n = part.rollouts() as i64;
        let part_json = part.json();
        // Shards of one submission finish one at a time (the submission row
        // is locked on PostgreSQL, the database on SQLite), so exactly one
        // of them sees every part and merges.
        let lock_submission = if self.is_postgres() {
            "SELECT suite FROM submissions WHERE id = $1 FOR UPDATE"
        } else {
            "SELECT suite FROM submissions WHERE id = $1"
        };
        on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            let submission_id: Option<i64> = sqlx::query_scalar(
                "SELECT submission_id FROM jobs WHERE id = $1 AND state = 'leased' AND lease_owner = $2",
            )
            .bind(job_id)
            .bind(owner)
            .fetch_optional(&mut *tx)
            .await?;
            let Some(submission_id) = submission_id else {
                return Err(StoreError::LeaseLost { job_id, owner: owner.to_string() });
            };
            let suite: Option<String> = sqlx::query_scalar(lock_submission)
                .bind(submission_id)
                .fetch_one(&mut *tx)
                .await?;
            sqlx::query(
                "UPDATE jobs SET state = 'done', lease_owner = NULL, lease_expires_at = NULL, finished_at = $1, \
                 rollouts_done = $2, rollouts_total = $2, sandbox_json = $3, part_json = $4, \
                 error_kind = NULL, error_message = NULL WHERE id = $5",
            )
            .bind(t)
            .bind(n)
            .bind(to_json(&mechanisms))
            .bind(&part_json)
            .bind(job_id)
            .execute(&mut *tx)
            .await?;
            let parts: Vec<(i64, String, Option<String>)> = sqlx::query_as(
                "SELECT shard_index, state, part_json FROM jobs WHERE submission_id = $1 ORDER BY shard_index",
            )
            .bind(submission_id)
            .fetch_all(&mut *tx)
            .await?;
            if parts.iter().any(|(_, state, _)| state != JobState::Done.as_str()) {
                tx.commit().await?;
                return Ok(false);
            }
            let rows = parts.into_iter().map(|(index, _, json)| (index, json)).collect();
            match Parts::decode(submission_id, rows, suite.is_some())?.merge() {
                Ok((result, doc)) => {
                    // The document first, as an unsharded suite job stores
                    // it (one transaction here).
                    if let Some(doc) = &doc {
                        insert_robustness!(&mut *tx, submission_id, doc);
                    }
                    insert_result!(&mut *tx, submission_id, &result, t);
                    // The parts are in the result now.
                    sqlx::query("UPDATE jobs SET part_json = NULL WHERE submission_id = $1")
                        .bind(submission_id)
                        .execute(&mut *tx)
                        .await?;
                }
                Err(e) => {
                    let message = format!("the shards could not be merged: {e}");
                    finish_failed!(&mut *tx, job_id, submission_id, "internal", &message, t);
                }
            }
            tx.commit().await?;
            Ok(true)
        })
    }
}
