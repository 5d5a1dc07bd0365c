//! Serving rendered rollout videos (the API's and the rollout page's
//! `<video>`): whole, or one byte range (206), as browsers ask when they
//! seek; tagged by the file's name, which says which build made it from
//! which record.

use crate::error::AppError;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use std::io::SeekFrom;
use tokio::io::{AsyncReadExt, AsyncSeekExt};

/// One byte range of a `len`-byte file, from a `Range` header: `Ok(None)`
/// for the whole file (no header, a unit other than bytes, several ranges:
/// RFC 9110 lets a server answer those with the whole), `Err(())` when the
/// range starts past the end (416).
fn byte_range(value: Option<&HeaderValue>, len: u64) -> Result<Option<(u64, u64)>, ()> {
    let Some(spec) = value
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().strip_prefix("bytes="))
    else {
        return Ok(None);
    };
    if spec.contains(',') {
        return Ok(None);
    }
    let Some((start, end)) = spec.trim().split_once('-') else {
        return Ok(None);
    };
    let (start, end) = (start.trim(), end.trim());
    let range = if start.is_empty() {
        // The last `end` bytes.
        let Ok(suffix) = end.parse::<u64>() else {
            return Ok(None);
        };
        if suffix == 0 {
            return Err(());
        }
        (len.saturating_sub(suffix), len.saturating_sub(1))
    } else {
        let Ok(first) = start.parse::<u64>() else {
            return Ok(None);
        };
        let last = match end {
            "" => len.saturating_sub(1),
            e => match e.parse::<u64>() {
                Ok(l) if l >= first => l.min(len.saturating_sub(1)),
                _ => return Ok(None),
            },
        };
        (first, last)
    };
    if range.0 >= len {
        return Err(());
    }
    Ok(Some(range))
}

/// The video file, whole (200) or the one byte range asked for (206);
/// immutable (its name says which build made it from which record), so
/// it is tagged by its name and length.
pub async fn serve_video(
    path: &std::path::Path,
    headers: &HeaderMap,
) -> Result<Response, AppError> {
    let io = |e: std::io::Error| AppError::Internal(format!("video {}: {e}", path.display()));
    let mut file = tokio::fs::File::open(path).await.map_err(io)?;
    let len = file.metadata().await.map_err(io)?.len();
    let tag = format!(
        "\"{}-{len:x}\"",
        path.file_stem()
            .map(|s| s.to_string_lossy())
            .unwrap_or_default()
    );
    let tag_value = HeaderValue::from_str(&tag).unwrap_or(HeaderValue::from_static("\"video\""));
    let mut common = HeaderMap::new();
    common.insert(header::CONTENT_TYPE, HeaderValue::from_static("video/mp4"));
    common.insert(header::ACCEPT_RANGES, HeaderValue::from_static("bytes"));
    common.insert(header::ETAG, tag_value.clone());
    common.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static("public, max-age=86400"),
    );
    let fresh = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|t| t.trim() == tag || t.trim() == "*"));
    if fresh {
        return Ok((StatusCode::NOT_MODIFIED, common).into_response());
    }
    // A range is honoured only for the video the client has part of.
    let if_range_ok = headers
        .get(header::IF_RANGE)
        .is_none_or(|v| v.to_str().is_ok_and(|v| v.trim() == tag));
    let range = if if_range_ok {
        byte_range(headers.get(header::RANGE), len)
    } else {
        Ok(None)
    };
    match range {
        Err(()) => {
            if let Ok(v) = HeaderValue::from_str(&format!("bytes */{len}")) {
                common.insert(header::CONTENT_RANGE, v);
            }
            Ok((StatusCode::RANGE_NOT_SATISFIABLE, common).into_response())
        }
        Ok(None) => {
            let mut body = Vec::with_capacity(len as usize);
            file.read_to_end(&mut body).await.map_err(io)?;
            Ok((StatusCode::OK, common, body).into_response())
        }
        Ok(Some((first, last))) => {
            let mut body = vec![0u8; (last - first + 1) as usize];
            file.seek(SeekFrom::Start(first)).await.map_err(io)?;
            file.read_exact(&mut body).await.map_err(io)?;
            if let Ok(v) = HeaderValue::from_str(&format!("bytes {first}-{last}/{len}")) {
                common.insert(header::CONTENT_RANGE, v);
            }
            Ok((StatusCode::PARTIAL_CONTENT, common, body).into_response())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::byte_range;
    use axum::http::HeaderValue;

    fn r(s: &str, len: u64) -> Result<Option<(u64, u64)>, ()> {
        byte_range(Some(&HeaderValue::from_str(s).unwrap()), len)
    }

    #[test]
    fn byte_ranges_as_rfc_9110_reads_them() {
        assert_eq!(r("bytes=0-99", 1000), Ok(Some((0, 99))));
        assert_eq!(r("bytes=990-2000", 1000), Ok(Some((990, 999))));
        assert_eq!(r("bytes=500-", 1000), Ok(Some((500, 999))));
        assert_eq!(r("bytes=-100", 1000), Ok(Some((900, 999))));
        assert_eq!(r("bytes=-5000", 1000), Ok(Some((0, 999))));
        assert_eq!(r("bytes=1000-", 1000), Err(()));
        assert_eq!(r("bytes=0-1,5-9", 1000), Ok(None));
        assert_eq!(r("items=0-1", 1000), Ok(None));
        assert_eq!(r("bytes=9-3", 1000), Ok(None));
        assert_eq!(byte_range(None, 1000), Ok(None));
    }
}
