//! The leaderboard as CSV (the API's and the pages' download).

use crate::error::AppError;
use crate::leaderboard::{protocol_str, BoardRow};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use d3il_protocol::Source;
use d3il_tables::write_csv;

pub fn csv_response(filename: &str, body: &str) -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{filename}\""),
            ),
        ],
        body.to_string(),
    )
        .into_response()
}

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        String::new()
    }
}

const HEADER: [&str; 18] = [
    "task",
    "obs_type",
    "method",
    "source",
    "protocol",
    "data_fraction",
    "control",
    "success_mean",
    "success_std",
    "conditional_entropy_mean",
    "conditional_entropy_std",
    "behaviour_entropy_mean",
    "behaviour_entropy_std",
    "n_seeds",
    "inference_ms",
    // Evaluated rows: rows on different sets, or image rows drawn with
    // different robot looks, are different rows.
    "initial_states",
    "robot_look",
    // The zoo's rows: "trained here on d3il demos v1"; empty
    // for submitted and reported rows.
    "data_source",
];

/// CSV of leaderboard rows (one header line, one line per row), written by
/// the tables crate's one CSV writer.
pub fn board_csv(rows: &[BoardRow]) -> Result<String, AppError> {
    write_csv(
        &HEADER,
        rows.iter().map(|r| {
            vec![
                r.task_title.clone(),
                r.obs.as_str().to_string(),
                r.method.clone(),
                match r.source {
                    Source::Reported => "reported".into(),
                    Source::Evaluated => "evaluated".into(),
                },
                r.protocol.map(protocol_str).unwrap_or("").to_string(),
                format!("{}", r.data_fraction),
                r.control.clone().unwrap_or_default(),
                num(r.success.mean),
                num(r.success.std),
                num(r.entropy.mean),
                num(r.entropy.std),
                r.behaviour_entropy.map(|s| num(s.mean)).unwrap_or_default(),
                r.behaviour_entropy.map(|s| num(s.std)).unwrap_or_default(),
                r.n_seeds.to_string(),
                r.inference_ms.map(num).unwrap_or_default(),
                r.initial_states.clone().unwrap_or_default(),
                r.robot_look.map(|l| l.as_str()).unwrap_or("").to_string(),
                r.data_source.clone().unwrap_or_default(),
            ]
        }),
    )
    .map_err(|e| AppError::Internal(e.to_string()))
}
