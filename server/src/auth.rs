//! Who is calling: the bearer-token extractor and the one token check (with
//! its rate limit) that the API and the HTML submit form share.

use crate::error::AppError;
use crate::state::AppState;
use crate::store::Submitter;
use axum::extract::FromRequestParts;
use axum::http::header;
use axum::http::request::Parts;

/// An authenticated, rate-limited API caller (`Authorization: Bearer <token>`).
pub struct Authed(pub Submitter);

impl FromRequestParts<AppState> for Authed {
    type Rejection = AppError;

    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, AppError> {
        let header = parts
            .headers
            .get(header::AUTHORIZATION)
            .ok_or_else(|| {
                AppError::Unauthorized(
                    "missing `Authorization: Bearer <token>` header; mint a token with `d3il token create --name <you>`".into(),
                )
            })?
            .to_str()
            .map_err(|_| AppError::Unauthorized("the Authorization header is not text".into()))?;
        // The auth scheme is case-insensitive (RFC 9110 §11.1).
        let token = header
            .split_once(' ')
            .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
            .map(|(_, t)| t.trim())
            .filter(|t| !t.is_empty())
            .ok_or_else(|| {
                AppError::Unauthorized("the Authorization header must be `Bearer <token>`".into())
            })?;
        authenticate_token(state, token).await.map(Authed)
    }
}

/// Checks a token and counts the request against its rate limit.
pub async fn authenticate_token(state: &AppState, token: &str) -> Result<Submitter, AppError> {
    let who = state.store.authenticate(token).await?.ok_or_else(|| {
        AppError::Unauthorized("the API token is unknown or revoked; mint a new one with `d3il token create --name <you>`".into())
    })?;
    state
        .limiter
        .check(who.token_id)
        .map_err(|retry_after| AppError::RateLimited { retry_after })?;
    Ok(who)
}
