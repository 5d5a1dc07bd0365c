//! Methods: the paper's baselines and those created by submissions.

use super::{Store, StoreError};

/// A method and its properties (as the paper lists them for its baselines).
#[derive(Debug, Clone, serde::Serialize, utoipa::ToSchema)]
pub struct MethodRow {
    pub id: i64,
    pub name: String,
    pub history: Option<i64>,
    pub backbone: Option<String>,
    pub prediction: Option<String>,
    pub diversity: Option<String>,
    pub code_url: Option<String>,
    pub paper_url: Option<String>,
    pub description: Option<String>,
    pub from_paper: bool,
    pub state_inference_ms: Option<f64>,
    pub image_inference_ms: Option<f64>,
    pub submitter_id: Option<i64>,
}

from_row!(MethodRow {
    id,
    name,
    history,
    backbone,
    prediction,
    diversity,
    code_url,
    paper_url,
    description,
    from_paper,
    state_inference_ms,
    image_inference_ms,
    submitter_id
});

/// Metadata for a new method created by a submission.
#[derive(Debug, Clone, Default)]
pub struct NewMethod {
    pub name: String,
    pub history: Option<i64>,
    pub backbone: Option<String>,
    pub prediction: Option<String>,
    pub diversity: Option<String>,
    pub code_url: Option<String>,
    pub paper_url: Option<String>,
    pub description: Option<String>,
}

impl Store {
    pub async fn methods(&self) -> Result<Vec<MethodRow>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT id, name, history, backbone, prediction, diversity, code_url, paper_url, description, \
             from_paper, state_inference_ms, image_inference_ms, submitter_id FROM methods ORDER BY from_paper DESC, id",
        )
        .fetch_all(pool)
        .await)?)
    }

    /// History and action chunking of every registered method, for the
    /// paper's tables (`d3il tables` and the home page; the paper's own
    /// methods use the paper's properties inside d3il-tables). The free-text
    /// `prediction` counts as action chunking when it mentions a chunk; a
    /// method without a history is treated as history-free.
    pub async fn method_infos(
        &self,
    ) -> Result<std::collections::BTreeMap<String, d3il_tables::MethodInfo>, StoreError> {
        Ok(self
            .methods()
            .await?
            .into_iter()
            .map(|m| {
                let info = d3il_tables::MethodInfo {
                    history: m.history.and_then(|h| u32::try_from(h).ok()).unwrap_or(1),
                    action_chunking: m
                        .prediction
                        .as_deref()
                        .is_some_and(|p| p.to_ascii_lowercase().contains("chunk")),
                };
                (m.name, info)
            })
            .collect())
    }

    pub async fn method_by_name(&self, name: &str) -> Result<Option<MethodRow>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT id, name, history, backbone, prediction, diversity, code_url, paper_url, description, \
             from_paper, state_inference_ms, image_inference_ms, submitter_id FROM methods WHERE name = $1",
        )
        .bind(name)
        .fetch_optional(pool)
        .await)?)
    }

    /// Returns the method with this name, creating it (owned by `submitter_id`)
    /// if it does not exist. Existing methods keep their metadata.
    pub async fn ensure_method(
        &self,
        m: &NewMethod,
        submitter_id: Option<i64>,
    ) -> Result<MethodRow, StoreError> {
        on_db!(&self.db, pool => sqlx::query(
            "INSERT INTO methods (name, history, backbone, prediction, diversity, code_url, paper_url, description, submitter_id) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9) ON CONFLICT(name) DO NOTHING",
        )
        .bind(&m.name)
        .bind(m.history)
        .bind(&m.backbone)
        .bind(&m.prediction)
        .bind(&m.diversity)
        .bind(&m.code_url)
        .bind(&m.paper_url)
        .bind(&m.description)
        .bind(submitter_id)
        .execute(pool)
        .await
        .map(|r| r.rows_affected()))?;
        self.method_by_name(&m.name)
            .await?
            .ok_or_else(|| StoreError::NotFound(format!("method `{}`", m.name)))
    }
}
