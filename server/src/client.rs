//! Blocking HTTP client for the `/api/v1` API (used by `d3il submit` and tests).

use crate::error::ErrorBody;
/// Re-exported so that callers (the root package's tests) need no own dependency.
pub use reqwest;
use serde_json::Value;
use std::path::Path;
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("cannot reach the server: {0}")]
    Http(#[from] reqwest::Error),
    #[error("the server refused the request ({status}, {code}){}: {message}", field.as_ref().map(|f| format!(" field `{f}`")).unwrap_or_default())]
    Api {
        status: u16,
        code: String,
        message: String,
        field: Option<String>,
    },
    #[error("cannot read {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    /// What was waited for ("submission 12", "race 3") and for how long.
    #[error("gave up waiting for {0} after {1:?}")]
    Timeout(String, Duration),
}

pub struct Client {
    base: String,
    token: Option<String>,
    http: reqwest::blocking::Client,
}

impl Client {
    /// `base` is the server root, e.g. `http://127.0.0.1:8080`.
    pub fn new(base: &str, token: Option<String>) -> Result<Client, ClientError> {
        Ok(Client {
            base: base.trim_end_matches('/').to_string(),
            token,
            http: reqwest::blocking::Client::builder()
                .timeout(Duration::from_secs(600))
                .build()?,
        })
    }

    fn auth(&self, rb: reqwest::blocking::RequestBuilder) -> reqwest::blocking::RequestBuilder {
        match &self.token {
            Some(t) => rb.bearer_auth(t),
            None => rb,
        }
    }

    fn decode(resp: reqwest::blocking::Response) -> Result<Value, ClientError> {
        let status = resp.status();
        let text = resp.text()?;
        if status.is_success() {
            return Ok(serde_json::from_str(&text).unwrap_or(Value::String(text)));
        }
        match serde_json::from_str::<ErrorBody>(&text) {
            Ok(b) => Err(ClientError::Api {
                status: status.as_u16(),
                code: b.error.code,
                message: b.error.message,
                field: b.error.field,
            }),
            Err(_) => Err(ClientError::Api {
                status: status.as_u16(),
                code: "unexpected".into(),
                message: text.chars().take(500).collect(),
                field: None,
            }),
        }
    }

    /// Creates a submission: text `fields` plus an optional ONNX file.
    pub fn submit(
        &self,
        fields: &[(&str, String)],
        onnx: Option<&Path>,
    ) -> Result<Value, ClientError> {
        let mut form = reqwest::blocking::multipart::Form::new();
        for (k, v) in fields {
            form = form.text(k.to_string(), v.clone());
        }
        if let Some(p) = onnx {
            // Streamed from the file (a policy can be hundreds of MB), with
            // its length so the server can refuse an oversized one at once.
            let io = |source| ClientError::Io {
                path: p.display().to_string(),
                source,
            };
            let file = std::fs::File::open(p).map_err(io)?;
            let len = file.metadata().map_err(io)?.len();
            let part = reqwest::blocking::multipart::Part::reader_with_length(file, len)
                .file_name(
                    p.file_name()
                        .map(|f| f.to_string_lossy().into_owned())
                        .unwrap_or_else(|| "policy.onnx".into()),
                )
                .mime_str("application/octet-stream")?;
            form = form.part("onnx", part);
        }
        let rb = self
            .http
            .post(format!("{}/api/v1/submissions", self.base))
            .multipart(form);
        Self::decode(self.auth(rb).send()?)
    }

    pub fn get(&self, path: &str) -> Result<Value, ClientError> {
        let rb = self.http.get(format!("{}{path}", self.base));
        Self::decode(self.auth(rb).send()?)
    }

    /// GET returning status and body text (pages, CSV, SVG).
    pub fn get_text(&self, path: &str) -> Result<(u16, String), ClientError> {
        let r = self
            .auth(self.http.get(format!("{}{path}", self.base)))
            .send()?;
        let status = r.status().as_u16();
        Ok((status, r.text()?))
    }

    /// Cancels a queued or running evaluation (`POST
    /// /api/v1/submissions/{id}/cancel`): what ran is kept, marked partial.
    pub fn cancel(&self, id: i64) -> Result<Value, ClientError> {
        let rb = self
            .http
            .post(format!("{}/api/v1/submissions/{id}/cancel", self.base));
        Self::decode(self.auth(rb).send()?)
    }

    /// Starts a race of two submissions (`POST /api/v1/races`); `body` is the request: `{"a", "b",
    /// "alpha"?, "delta"?, "protocol"?, "seed"?, "task"?}`.
    pub fn race(&self, body: &Value) -> Result<Value, ClientError> {
        let rb = self
            .http
            .post(format!("{}/api/v1/races", self.base))
            .json(body);
        Self::decode(self.auth(rb).send()?)
    }

    /// Cancels a queued or running race (`POST
    /// /api/v1/races/{id}/cancel`): its starter or an admin.
    pub fn cancel_race(&self, id: i64) -> Result<Value, ClientError> {
        let rb = self
            .http
            .post(format!("{}/api/v1/races/{id}/cancel", self.base));
        Self::decode(self.auth(rb).send()?)
    }

    /// A race (`GET /api/v1/races/{id}`).
    pub fn get_race(&self, id: i64) -> Result<Value, ClientError> {
        self.get(&format!("/api/v1/races/{id}"))
    }

    /// Polls a race until it is completed, failed or cancelled.
    pub fn wait_race(
        &self,
        id: i64,
        timeout: Duration,
        on_update: impl FnMut(&Value),
    ) -> Result<Value, ClientError> {
        let path = format!("/api/v1/races/{id}");
        let what = format!("race {id}");
        self.poll_until_done(&path, &what, timeout, Duration::from_millis(300), on_update)
    }

    /// GETs `path` every `every` until its `status` is completed, failed
    /// or (a race) cancelled.
    fn poll_until_done(
        &self,
        path: &str,
        what: &str,
        timeout: Duration,
        every: Duration,
        mut on_update: impl FnMut(&Value),
    ) -> Result<Value, ClientError> {
        let start = Instant::now();
        loop {
            let v = self.get(path)?;
            on_update(&v);
            if matches!(
                v["status"].as_str(),
                Some("completed") | Some("failed") | Some("cancelled")
            ) {
                return Ok(v);
            }
            if start.elapsed() > timeout {
                return Err(ClientError::Timeout(what.to_string(), timeout));
            }
            std::thread::sleep(every);
        }
    }

    pub fn submission(&self, id: i64) -> Result<Value, ClientError> {
        self.get(&format!("/api/v1/submissions/{id}"))
    }

    /// Polls until the submission is completed or failed.
    pub fn wait(
        &self,
        id: i64,
        timeout: Duration,
        on_update: impl FnMut(&Value),
    ) -> Result<Value, ClientError> {
        let path = format!("/api/v1/submissions/{id}");
        let what = format!("submission {id}");
        self.poll_until_done(&path, &what, timeout, Duration::from_millis(500), on_update)
    }
}
