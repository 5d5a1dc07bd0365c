//! API tokens and the submitters they belong to. Only a token's SHA-256 is
//! stored.

use super::{now, Store, StoreError};
use sha2::{Digest, Sha256};

#[derive(Debug, Clone)]
pub struct Submitter {
    pub id: i64,
    pub name: String,
    /// The token that authenticated this request.
    pub token_id: i64,
    /// An operator's token (`d3il token create --admin`): may see `/admin`.
    pub is_admin: bool,
    /// When the token was last used (as recorded: at most once a minute).
    pub last_used_at: Option<i64>,
}

from_row!(Submitter {
    id,
    name,
    token_id,
    is_admin,
    last_used_at
});

/// `last_used_at` is written at most this often per token.
pub const LAST_USED_RESOLUTION_S: i64 = 60;

/// What `d3il token revoke` did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Revoked {
    /// Prefixes of the tokens revoked now.
    pub prefixes: Vec<String>,
    /// The audit entry written with it.
    pub audit: super::AuditEntry,
}

impl Store {
    /// Mints a new API token for `name` (creating the submitter). Returns the
    /// plaintext token, which is shown once: only its SHA-256 is stored.
    pub async fn create_token(&self, name: &str) -> Result<String, StoreError> {
        self.create_token_with(name, false).await
    }

    /// As [`Store::create_token`]; `admin` tokens may also see `/admin`.
    pub async fn create_token_with(&self, name: &str, admin: bool) -> Result<String, StoreError> {
        let mut raw = [0u8; 24];
        getrandom::fill(&mut raw)
            .map_err(|e| StoreError::Corrupt(format!("no randomness available: {e}")))?;
        let token = format!("d3il_{}", hex::encode(raw));
        on_db!(&self.db, pool => {
        let mut tx = begin_write!(self, pool);
        sqlx::query("INSERT INTO submitters (name) VALUES ($1) ON CONFLICT(name) DO NOTHING")
            .bind(name)
            .execute(&mut *tx)
            .await?;
        let submitter_id: i64 = sqlx::query_scalar("SELECT id FROM submitters WHERE name = $1")
            .bind(name)
            .fetch_one(&mut *tx)
            .await?;
        sqlx::query(
            "INSERT INTO api_tokens (submitter_id, token_sha256, prefix, is_admin) VALUES ($1, $2, $3, $4)",
        )
        .bind(submitter_id)
        .bind(token_hash(&token))
        .bind(&token[..TOKEN_PREFIX_LEN])
        .bind(admin)
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok::<(), StoreError>(())
        })?;
        Ok(token)
    }

    /// The submitter owning this (unrevoked) token, if any.
    pub async fn authenticate(&self, token: &str) -> Result<Option<Submitter>, StoreError> {
        let row: Option<Submitter> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT s.id, s.name, t.id AS token_id, t.is_admin, t.last_used_at FROM api_tokens t JOIN submitters s ON s.id = t.submitter_id \
             WHERE t.token_sha256 = $1 AND t.revoked_at IS NULL",
        )
        .bind(token_hash(token))
        .fetch_optional(pool)
        .await)?;
        // Recording the use is bookkeeping, not the request's business: it
        // is written at most once a minute, in the background, so a held
        // write lock never delays or fails an authenticated read.
        if let Some(s) = &row {
            let t = now();
            let due = |at: Option<i64>| at.is_none_or(|at| t - at >= LAST_USED_RESOLUTION_S);
            let write = due(s.last_used_at) && {
                let mut written = self
                    .last_used
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                let due_here = due(written.get(&s.token_id).copied());
                if due_here {
                    written.insert(s.token_id, t);
                }
                due_here
            };
            if write {
                let db = self.db.clone();
                let id = s.token_id;
                tokio::spawn(async move {
                    let r = on_db!(&db, pool => sqlx::query(
                        "UPDATE api_tokens SET last_used_at = $1 WHERE id = $2 \
                         AND (last_used_at IS NULL OR last_used_at <= $3)",
                    )
                    .bind(t)
                    .bind(id)
                    .bind(t - LAST_USED_RESOLUTION_S)
                    .execute(pool)
                    .await
                    .map(|_| ()));
                    if let Err(e) = r {
                        tracing::warn!("token {id}: last_used_at not recorded: {e}");
                    }
                });
            }
        }
        Ok(row)
    }
}

/// How much of a token is stored in clear (and printed) to name it.
pub const TOKEN_PREFIX_LEN: usize = 13;

impl Store {
    /// Revokes a token, given either the whole token or its stored prefix
    /// (the first 13 characters, as `d3il token create` prints them). Tokens
    /// revoked before are not counted again; an unknown one is `NotFound`.
    pub async fn revoke_token(
        &self,
        token_or_prefix: &str,
        actor: &str,
    ) -> Result<Revoked, StoreError> {
        let t = token_or_prefix.trim();
        let rows: Vec<(i64, String, Option<i64>)> = if t.len() > TOKEN_PREFIX_LEN {
            on_db!(&self.db, pool => sqlx::query_as("SELECT id, prefix, revoked_at FROM api_tokens WHERE token_sha256 = $1")
                .bind(token_hash(t))
                .fetch_all(pool)
                .await)?
        } else {
            // A prefix that names more than one live token is refused (issue
            // 52: it used to revoke them all), naming them, so the operator
            // can give the whole token instead.
            let live: Vec<(String, i64)> = on_db!(&self.db, pool => sqlx::query_as(
                "SELECT s.name, t.created_at FROM api_tokens t JOIN submitters s ON s.id = t.submitter_id \
                 WHERE t.prefix = $1 AND t.revoked_at IS NULL ORDER BY t.id",
            )
            .bind(t)
            .fetch_all(pool)
            .await)?;
            if live.len() > 1 {
                let names: Vec<String> = live
                    .iter()
                    .map(|(name, at)| format!("{name}'s (created at unix {at})"))
                    .collect();
                return Err(StoreError::Conflict(format!(
                    "the prefix `{t}` names {} live tokens: {}; give the whole token to revoke one",
                    live.len(),
                    names.join(", ")
                )));
            }
            on_db!(&self.db, pool => sqlx::query_as("SELECT id, prefix, revoked_at FROM api_tokens WHERE prefix = $1")
                .bind(t)
                .fetch_all(pool)
                .await)?
        };
        if rows.is_empty() {
            return Err(StoreError::NotFound(format!(
                "a token `{t}` (give the whole token or the 13-character prefix `d3il_…` shown when it was created)"
            )));
        }
        // The revocation and its audit entry commit together.
        let live: Vec<(i64, String)> = rows
            .into_iter()
            .filter(|r| r.2.is_none())
            .map(|(id, prefix, _)| (id, prefix))
            .collect();
        let prefixes: Vec<String> = live.iter().map(|r| r.1.clone()).collect();
        let detail = if prefixes.is_empty() {
            "already revoked".to_string()
        } else {
            format!("revoked {}", prefixes.join(", "))
        };
        // Never the whole token: its first characters name it.
        let target = format!(
            "token {}",
            t.chars().take(TOKEN_PREFIX_LEN).collect::<String>()
        );
        let audit = on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            for (id, _) in &live {
                sqlx::query("UPDATE api_tokens SET revoked_at = $1 WHERE id = $2 AND revoked_at IS NULL")
                    .bind(now())
                    .bind(id)
                    .execute(&mut *tx)
                    .await?;
            }
            let e: super::AuditEntry = sqlx::query_as(
                "INSERT INTO audit_log (at, actor, action, target, detail) VALUES ($1, $2, 'revoke_token', $3, $4) \
                 RETURNING id, at, actor, action, target, detail",
            )
            .bind(now())
            .bind(actor)
            .bind(&target)
            .bind(&detail)
            .fetch_one(&mut *tx)
            .await?;
            tx.commit().await?;
            e
        });
        Ok(Revoked { prefixes, audit })
    }
}

pub fn token_hash(token: &str) -> String {
    hex::encode(Sha256::digest(token.as_bytes()))
}
