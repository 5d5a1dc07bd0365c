//! Who is calling: the bearer-token extractor and the one token check (with
//! its rate limit) that the API and the HTML submit form share.
//! The rate-limit layer checks the token of every request that carries one
//! ([`verify_header`]): only a valid token lifts the anonymous rate limit; an
//! unknown one is a 401 counted against the failed-auth limit. The caller
//! it found ([`Verified`]) is what the extractors below then use.

use crate::error::AppError;
use crate::state::AppState;
use crate::store::Submitter;
use axum::extract::FromRequestParts;
use axum::http::header;
use axum::http::request::Parts;

/// An authenticated, rate-limited API caller (`Authorization: Bearer <token>`).
pub struct Authed(pub Submitter);

/// The caller whose token the rate-limit layer checked (a request
/// extension): not looked up again, only counted against its rate limit.
#[derive(Debug, Clone)]
pub struct Verified(pub Submitter);

impl FromRequestParts<AppState> for Authed {
    type Rejection = AppError;

    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, AppError> {
        if let Some(Verified(who)) = parts.extensions.get::<Verified>().cloned() {
            return count_request(state, who).map(Authed);
        }
        let token = bearer_token(parts)?;
        authenticate_token(state, token).await.map(Authed)
    }
}

/// The token an `Authorization` header carries: `Bearer <token>`, or the
/// password of HTTP Basic (the admin page's browser prompt); None when the
/// header is neither.
pub fn token_in_header(value: &str) -> Option<String> {
    let (scheme, rest) = value.split_once(' ')?;
    if scheme.eq_ignore_ascii_case("bearer") {
        return Some(rest.trim().to_string()).filter(|t| !t.is_empty());
    }
    if scheme.eq_ignore_ascii_case("basic") {
        use base64::Engine;
        let raw = base64::engine::general_purpose::STANDARD
            .decode(rest.trim())
            .ok()?;
        let text = String::from_utf8(raw).ok()?;
        let (_, password) = text.split_once(':')?;
        return Some(password.trim().to_string()).filter(|t| !t.is_empty());
    }
    None
}

/// The caller of a request's `Authorization` header (the rate-limit layer's
/// check): `Ok(Some)` for a valid token, `Ok(None)` without the header, and
/// a 401 for a header that names no valid token (malformed, unknown or
/// revoked). Not counted against the token's rate limit here.
pub async fn verify_header(
    state: &AppState,
    headers: &axum::http::HeaderMap,
) -> Result<Option<Submitter>, AppError> {
    let Some(value) = headers.get(header::AUTHORIZATION) else {
        return Ok(None);
    };
    let token = value.to_str().ok().and_then(token_in_header).ok_or_else(|| {
        AppError::Unauthorized(
            "the Authorization header must be `Bearer <token>`; leave it out to browse without a token".into(),
        )
    })?;
    let who = state.store.authenticate(&token).await?.ok_or_else(|| {
        AppError::Unauthorized(
            "the API token is unknown or revoked; mint a new one with `d3il token create --name <you>`, \
             or leave the Authorization header out to browse without a token"
                .into(),
        )
    })?;
    Ok(Some(who))
}

/// The token of `Authorization: Bearer <token>`.
fn bearer_token(parts: &Parts) -> Result<&str, AppError> {
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
    Ok(token)
}

/// An operator (`/admin`): an admin token (`d3il token create --admin`) as
/// `Authorization: Bearer <token>`, or as the password of HTTP Basic
/// authentication so a browser can ask for it (any user name).
pub struct Admin(pub Submitter);

const ADMIN_HINT: &str =
    "the admin page needs an admin token; mint one with `d3il token create --admin --name <you>` \
     and send it as `Authorization: Bearer <token>` (or as the password when the browser asks)";

impl FromRequestParts<AppState> for Admin {
    type Rejection = AppError;

    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, AppError> {
        if let Some(Verified(who)) = parts.extensions.get::<Verified>().cloned() {
            let who = count_request(state, who)?;
            if !who.is_admin {
                return Err(AppError::Forbidden(format!(
                    "the token of `{}` is not an admin token; {ADMIN_HINT}",
                    who.name
                )));
            }
            return Ok(Admin(who));
        }
        let header = parts
            .headers
            .get(header::AUTHORIZATION)
            .and_then(|h| h.to_str().ok())
            .ok_or_else(|| AppError::Unauthorized(ADMIN_HINT.into()))?;
        let token = match header.split_once(' ') {
            Some((scheme, b64)) if scheme.eq_ignore_ascii_case("basic") => {
                use base64::Engine;
                let raw = base64::engine::general_purpose::STANDARD
                    .decode(b64.trim())
                    .map_err(|_| AppError::Unauthorized(ADMIN_HINT.into()))?;
                let text = String::from_utf8(raw)
                    .map_err(|_| AppError::Unauthorized(ADMIN_HINT.into()))?;
                let (_, password) = text
                    .split_once(':')
                    .ok_or_else(|| AppError::Unauthorized(ADMIN_HINT.into()))?;
                password.trim().to_string()
            }
            _ => bearer_token(parts)?.to_string(),
        };
        let who = authenticate_token(state, &token).await?;
        if !who.is_admin {
            return Err(AppError::Forbidden(format!(
                "the token of `{}` is not an admin token; {ADMIN_HINT}",
                who.name
            )));
        }
        Ok(Admin(who))
    }
}

/// Checks a token and counts the request against its rate limit.
pub async fn authenticate_token(state: &AppState, token: &str) -> Result<Submitter, AppError> {
    let who = state.store.authenticate(token).await?.ok_or_else(|| {
        AppError::Unauthorized("the API token is unknown or revoked; mint a new one with `d3il token create --name <you>`".into())
    })?;
    count_request(state, who)
}

/// Counts a request of `who` against its token's rate limit.
fn count_request(state: &AppState, who: Submitter) -> Result<Submitter, AppError> {
    state
        .limiter
        .check(who.token_id)
        .map_err(|retry_after| AppError::RateLimited {
            retry_after,
            limit: crate::error::RATE_LIMIT_TOKEN,
        })?;
    Ok(who)
}
