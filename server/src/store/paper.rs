//! The paper's methods and reported results: loaded on every start
//! (idempotently) and read back as leaderboard rows.

use super::types::Stored;
use super::{Store, StoreError};
use crate::leaderboard::{task_for_title, BoardRow};
use d3il_protocol::paper::PaperResults;
use d3il_protocol::{ObsType, Source, Stat};

struct ReportedDbRow {
    paper_table: String,
    method: String,
    method_id: i64,
    task_title: String,
    obs_type: ObsType,
    data_fraction: f64,
    control: String,
    success_mean: f64,
    success_std: f64,
    success_bold: bool,
    entropy_mean: f64,
    entropy_std: f64,
    entropy_bold: bool,
    n_seeds: i64,
    state_inference_ms: Option<f64>,
    image_inference_ms: Option<f64>,
}

from_row!(ReportedDbRow { paper_table, method, method_id, task_title, obs_type: Stored<ObsType>, data_fraction, control, success_mean, success_std, success_bold, entropy_mean, entropy_std, entropy_bold, n_seeds, state_inference_ms, image_inference_ms });

impl Store {
    /// Inserts the paper's methods and reported rows; rows already present are
    /// left untouched, so this runs on every start.
    pub async fn load_paper(&self, paper: &PaperResults) -> Result<(), StoreError> {
        on_db!(&self.db, pool => {
        let mut tx = begin_write!(self, pool);
        for (name, m) in &paper.methods {
            sqlx::query(
                "INSERT INTO methods (name, history, backbone, prediction, diversity, paper_url, description, \
                 from_paper, state_inference_ms, image_inference_ms) VALUES ($1, $2, $3, $4, $5, $6, $7, TRUE, $8, $9) \
                 ON CONFLICT(name) DO NOTHING",
            )
            .bind(name)
            .bind(m.history as i64)
            .bind(&m.backbone)
            .bind(&m.prediction)
            .bind(&m.diversity)
            .bind(&paper.source)
            .bind("Baseline of the D3IL paper; numbers are as reported there.")
            .bind(m.inference_ms.state_ms)
            .bind(m.inference_ms.image_ms)
            .execute(&mut *tx)
            .await?;
        }
        for r in &paper.results {
            let method_id: i64 = sqlx::query_scalar("SELECT id FROM methods WHERE name = $1")
                .bind(&r.method)
                .fetch_optional(&mut *tx)
                .await?
                .ok_or_else(|| {
                    StoreError::Corrupt(format!(
                        "paper row for unknown method `{}` (not in the methods table)",
                        r.method
                    ))
                })?;
            sqlx::query(
                "INSERT INTO reported_results (paper_table, method_id, task_title, obs_type, data_fraction, control, \
                 success_mean, success_std, success_bold, entropy_mean, entropy_std, entropy_bold, n_seeds, subtasks_json) \
                 VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14) \
                 ON CONFLICT(paper_table, method_id, task_title, obs_type, data_fraction, control) DO NOTHING",
            )
            .bind(&r.table)
            .bind(method_id)
            .bind(&r.task)
            .bind(&r.obs)
            .bind(r.data_fraction)
            .bind(r.control.clone().unwrap_or_default())
            .bind(r.success_rate.mean)
            .bind(r.success_rate.std)
            .bind(r.success_rate.bold)
            .bind(r.entropy.mean)
            .bind(r.entropy.std)
            .bind(r.entropy.bold)
            .bind(r.seeds as i64)
            .bind(r.subtasks.as_ref().map(|v| v.to_string()))
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
        })
    }

    pub(super) async fn reported_rows(&self) -> Result<Vec<BoardRow>, StoreError> {
        let db: Vec<ReportedDbRow> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT r.paper_table, m.name AS method, m.id AS method_id, r.task_title, r.obs_type, r.data_fraction, \
             r.control, r.success_mean, r.success_std, r.success_bold, r.entropy_mean, r.entropy_std, r.entropy_bold, \
             r.n_seeds, m.state_inference_ms, m.image_inference_ms \
             FROM reported_results r JOIN methods m ON m.id = r.method_id ORDER BY r.id",
        )
        .fetch_all(pool)
        .await)?;
        Ok(db
            .into_iter()
            .map(|r| {
                let obs = r.obs_type;
                BoardRow {
                    baseline: false,
                    method: r.method,
                    method_id: r.method_id,
                    paper_table: r.paper_table,
                    task: task_for_title(&r.task_title),
                    task_title: r.task_title,
                    obs,
                    data_fraction: r.data_fraction,
                    control: (!r.control.is_empty()).then_some(r.control),
                    source: Source::Reported,
                    protocol: None,
                    success: Stat {
                        mean: r.success_mean,
                        std: r.success_std,
                    },
                    entropy: Stat {
                        mean: r.entropy_mean,
                        std: r.entropy_std,
                    },
                    behaviour_entropy: None,
                    n_seeds: r.n_seeds.max(0) as usize,
                    inference_ms: match obs {
                        ObsType::State => r.state_inference_ms,
                        ObsType::Image => r.image_inference_ms,
                    },
                    bold_success: Some(r.success_bold),
                    bold_entropy: Some(r.entropy_bold),
                    submission_ids: vec![],
                    initial_states: None,
                    initial_states_label: None,
                    robot_look: None,
                    physics_fingerprint: None,
                    data_source: None,
                }
            })
            .collect())
    }
}
