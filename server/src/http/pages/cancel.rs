//! The submission page's Cancel button: `POST
//! /submissions/{id}/cancel` with the submitter's (or an admin's) token, then
//! back to the page, which shows the partial result.

use crate::auth::authenticate_token;
use crate::cancel::cancel_as;
use crate::error::PageError;
use crate::http::extract::Param;
use crate::state::AppState;
use axum::extract::State;
use axum::response::{IntoResponse, Redirect, Response};
use axum::Form;
use serde::Deserialize;

/// A Cancel button's form (the submission page's and the race page's).
#[derive(Deserialize)]
pub(super) struct CancelForm {
    #[serde(default)]
    pub(super) token: String,
}

pub(super) async fn cancel_post(
    State(state): State<AppState>,
    Param(id): Param<i64>,
    Form(f): Form<CancelForm>,
) -> Result<Response, PageError> {
    let who = authenticate_token(&state, f.token.trim()).await?;
    cancel_as(&state, id, &who).await?;
    Ok(Redirect::to(&format!("/submissions/{id}")).into_response())
}
