//! API tokens and the submitters they belong to. Only a token's SHA-256 is
//! stored.

use super::{now, Store, StoreError};
use sha2::{Digest, Sha256};
use sqlx::FromRow;

#[derive(Debug, Clone, FromRow)]
pub struct Submitter {
    pub id: i64,
    pub name: String,
    /// The token that authenticated this request.
    pub token_id: i64,
}

impl Store {
    /// Mints a new API token for `name` (creating the submitter). Returns the
    /// plaintext token, which is shown once: only its SHA-256 is stored.
    pub async fn create_token(&self, name: &str) -> Result<String, StoreError> {
        let mut raw = [0u8; 24];
        getrandom::fill(&mut raw)
            .map_err(|e| StoreError::Corrupt(format!("no randomness available: {e}")))?;
        let token = format!("d3il_{}", hex::encode(raw));
        let mut tx = self.pool.begin().await?;
        sqlx::query("INSERT INTO submitters (name) VALUES (?) ON CONFLICT(name) DO NOTHING")
            .bind(name)
            .execute(&mut *tx)
            .await?;
        let submitter_id: i64 = sqlx::query_scalar("SELECT id FROM submitters WHERE name = ?")
            .bind(name)
            .fetch_one(&mut *tx)
            .await?;
        sqlx::query("INSERT INTO api_tokens (submitter_id, token_sha256, prefix) VALUES (?, ?, ?)")
            .bind(submitter_id)
            .bind(token_hash(&token))
            .bind(&token[..13])
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(token)
    }

    /// The submitter owning this (unrevoked) token, if any.
    pub async fn authenticate(&self, token: &str) -> Result<Option<Submitter>, StoreError> {
        let row: Option<Submitter> = sqlx::query_as(
            "SELECT s.id, s.name, t.id AS token_id FROM api_tokens t JOIN submitters s ON s.id = t.submitter_id \
             WHERE t.token_sha256 = ? AND t.revoked_at IS NULL",
        )
        .bind(token_hash(token))
        .fetch_optional(&self.pool)
        .await?;
        if let Some(s) = &row {
            sqlx::query("UPDATE api_tokens SET last_used_at = ? WHERE id = ?")
                .bind(now())
                .bind(s.token_id)
                .execute(&self.pool)
                .await?;
        }
        Ok(row)
    }
}

pub fn token_hash(token: &str) -> String {
    hex::encode(Sha256::digest(token.as_bytes()))
}
