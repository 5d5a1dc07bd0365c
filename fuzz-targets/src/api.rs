//! The HTTP front: the real router ([`d3il_server::app::router`]) over a
//! real SQLite store in a scratch directory, called in process (no socket),
//! the same stack `d3il serve` runs behind hyper. Properties: bad input is
//! answered 4xx with a message (under `/api/` the JSON error body with a
//! non-empty `message`), never 5xx or a panic; a refused upload leaves no
//! temporary file behind.

use axum::body::Body;
use axum::http::{header, Request, StatusCode};
use d3il_protocol::{EvalResult, Job, WorkerError};
use d3il_server::app::{prepare, router, AppState, ServerConfig};
use d3il_server::queue::{JobRunner, RunReport};
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};
use tower::ServiceExt;

/// The endpoint dry-run of a remote submission, without a worker: every
/// endpoint is refused as unreachable (a remote endpoint's conformance run
/// is the remote_frame target's business, not the upload path's).
struct NoEndpoints;

impl JobRunner for NoEndpoints {
    fn run(&self, _job: &Job, _progress: &mut dyn FnMut(usize, usize)) -> RunReport {
        RunReport {
            outcome: Err(WorkerError {
                kind: d3il_protocol::ErrorKind::Remote,
                message: "the fuzz harness connects to no endpoint".into(),
            }),
            mechanisms: vec![],
        }
    }
}

struct Server {
    rt: tokio::runtime::Runtime,
    state: AppState,
    token: String,
    _dir: PathBuf,
}

/// One server per process: opening the store and its migrations once.
fn server() -> &'static Server {
    static S: OnceLock<Server> = OnceLock::new();
    S.get_or_init(|| {
        // Named after the parent: afl's fork server starts a fresh child
        // every so many runs, which starts over in the same directory.
        let dir = std::env::temp_dir().join(format!(
            "d3il-fuzz-api-{}-{}",
            std::os::unix::process::parent_id(),
            std::env::args().nth(1).unwrap_or_default()
        ));
        remove_stale_scratch();
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("scratch directory");
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("tokio runtime");
        let mut cfg = ServerConfig::new(
            dir.join("fuzz.sqlite"),
            "127.0.0.1:0".parse().expect("address"),
            PathBuf::from("/bin/false"),
        );
        cfg.workers = 0;
        cfg.dry_run_uploads = false;
        cfg.rate_limit_per_minute = u32::MAX;
        cfg.max_upload_bytes = 64 << 10;
        let (state, token) = rt.block_on(async {
            let (_listener, running) = prepare(cfg, Arc::new(NoEndpoints))
                .await
                .expect("the server starts");
            let token = running
                .state
                .store
                .create_token("fuzzer")
                .await
                .expect("token");
            (running.state, token)
        });
        let s = Server {
            rt,
            state,
            token,
            _dir: dir,
        };
        s.seed_result();
        s
    })
}

/// Scratch directories of earlier runs whose process is gone.
fn remove_stale_scratch() {
    for entry in std::fs::read_dir(std::env::temp_dir())
        .into_iter()
        .flatten()
        .flatten()
    {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(pid) = name
            .strip_prefix("d3il-fuzz-api-")
            .and_then(|rest| rest.split('-').next())
        else {
            continue;
        };
        if !pid.is_empty() && !std::path::Path::new("/proc").join(pid).exists() {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

impl Server {
    fn call(&self, req: Request<Body>) -> (StatusCode, Vec<u8>) {
        self.rt.block_on(async {
            let resp = router(self.state.clone())
                .oneshot(req)
                .await
                .expect("the router is infallible");
            let status = resp.status();
            let body = axum::body::to_bytes(resp.into_body(), 64 << 20)
                .await
                .expect("a response body reads");
            (status, body.to_vec())
        })
    }

    /// Submission 1: an Avoiding evaluation with its rollouts (what the
    /// rollout filters and pages read).
    fn seed_result(&self) {
        let manifest = r#"{"task": "avoiding", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#;
        let body = form(
            &[
                ("method", "Seed"),
                ("task", "avoiding"),
                ("training_seed", "0"),
                ("manifest", manifest),
            ],
            Some(&[7u8; 64]),
        );
        let (status, text) =
            self.call(self.post("/api/v1/submissions", FORM_TYPE, true, body.into()));
        assert_eq!(
            status,
            StatusCode::CREATED,
            "{}",
            String::from_utf8_lossy(&text)
        );
        let result: EvalResult =
            serde_json::from_str(include_str!("../data/avoiding-quick-result.json"))
                .expect("the seed result parses");
        self.rt.block_on(async {
            let store = &self.state.store;
            let job = store.job_for(1).await.expect("job of submission 1");
            store
                .complete_job(job.id, 1, &result, &[])
                .await
                .expect("complete");
        });
    }

    fn post(&self, path: &str, content_type: &str, bearer: bool, body: Body) -> Request<Body> {
        let mut req = Request::post(path).header(header::CONTENT_TYPE, content_type);
        if bearer {
            req = req.header(header::AUTHORIZATION, format!("Bearer {}", self.token));
        }
        req.body(body).expect("a request builds")
    }

    /// Temporary uploads left in the policy store.
    fn leftover_uploads(&self) -> Vec<String> {
        std::fs::read_dir(self.state.store.policies_dir())
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.contains(".tmp"))
            .collect()
    }
}

const BOUNDARY: &str = "d3ilfuzz";
const FORM_TYPE: &str = "multipart/form-data; boundary=d3ilfuzz";

/// A multipart body with `fields` and an optional `onnx` file (seeds).
pub fn form(fields: &[(&str, &str)], onnx: Option<&[u8]>) -> Vec<u8> {
    let mut b = Vec::new();
    for (k, v) in fields {
        b.extend_from_slice(
            format!("--{BOUNDARY}\r\nContent-Disposition: form-data; name=\"{k}\"\r\n\r\n{v}\r\n")
                .as_bytes(),
        );
    }
    if let Some(f) = onnx {
        b.extend_from_slice(
            format!("--{BOUNDARY}\r\nContent-Disposition: form-data; name=\"onnx\"; filename=\"p.onnx\"\r\nContent-Type: application/octet-stream\r\n\r\n").as_bytes(),
        );
        b.extend_from_slice(f);
        b.extend_from_slice(b"\r\n");
    }
    b.extend_from_slice(format!("--{BOUNDARY}--\r\n").as_bytes());
    b
}

/// The answer must be what the route promises for bad input: no 5xx, and
/// a 4xx that says what is wrong (JSON `error.message` under `/api/`, a
/// page with text elsewhere).
fn check_answer(what: &str, api: bool, status: StatusCode, body: &[u8]) {
    let text = String::from_utf8_lossy(body);
    if std::env::var_os("D3IL_FUZZ_VERBOSE").is_some() {
        eprintln!(
            "{what}: {status} {}",
            text.chars().take(300).collect::<String>()
        );
    }
    assert!(
        !status.is_server_error(),
        "{what}: answered {status}: {text}"
    );
    if status.is_client_error() && status != StatusCode::NOT_MODIFIED {
        if api {
            let e: d3il_server::error::ErrorBody =
                serde_json::from_slice(body).unwrap_or_else(|e| {
                    panic!("{what}: a {status} without the JSON error body ({e}): {text}")
                });
            assert!(
                e.error.message.trim().len() >= 8,
                "{what}: a {status} without a usable message: {text}"
            );
        } else {
            assert!(
                text.trim().len() >= 8,
                "{what}: a {status} with an empty page"
            );
        }
    }
}

/// A submission upload. The input is one line `<route> <content type>`,
/// then the body: `api` posts to `/api/v1/submissions` with the bearer
/// token, `form` to the HTML form's `/submit` (where `@TOKEN@` in the body
/// becomes the real token); `-cut` after the route ends the body with a
/// transport error, as a client that goes away mid-upload. The body streams
/// in chunks whose size the input's length sets, so the multipart reader
/// sees boundaries split across chunks.
pub fn upload(data: &[u8]) {
    let Some(nl) = data.iter().position(|&b| b == b'\n') else {
        return;
    };
    let Ok(head) = std::str::from_utf8(&data[..nl]) else {
        return;
    };
    let (route, content_type) = head.split_once(' ').unwrap_or((head, ""));
    let (route, cut) = match route.strip_suffix("-cut") {
        Some(r) => (r, true),
        None => (route, false),
    };
    let (path, api) = match route {
        "api" => ("/api/v1/submissions", true),
        "form" => ("/submit", false),
        _ => return,
    };
    let s = server();
    let body = replace(&data[nl + 1..], b"@TOKEN@", s.token.as_bytes());
    let chunk = 1 + data.len() % 97;
    let mut chunks: Vec<Result<Vec<u8>, std::io::Error>> =
        body.chunks(chunk).map(|c| Ok(c.to_vec())).collect();
    if cut {
        chunks.push(Err(std::io::Error::new(
            std::io::ErrorKind::ConnectionReset,
            "the client went away",
        )));
    }
    let Ok(req) = Request::post(path)
        .header(header::CONTENT_TYPE, content_type)
        .header(header::AUTHORIZATION, format!("Bearer {}", s.token))
        .body(Body::from_stream(futures_stream(chunks)))
    else {
        // hyper refuses a header value it cannot carry before any route.
        return;
    };
    let (status, resp) = s.call(req);
    check_answer(head, api, status, &resp);
    let left = s.leftover_uploads();
    assert!(
        left.is_empty(),
        "{head}: temporary uploads left behind: {left:?}"
    );
}

fn futures_stream(
    chunks: Vec<Result<Vec<u8>, std::io::Error>>,
) -> impl futures_util::Stream<Item = Result<Vec<u8>, std::io::Error>> {
    futures_util::stream::iter(chunks)
}

fn replace(hay: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(hay.len());
    let mut i = 0;
    while i < hay.len() {
        if hay[i..].starts_with(from) {
            out.extend_from_slice(to);
            i += from.len();
        } else {
            out.push(hay[i]);
            i += 1;
        }
    }
    out
}

/// GET routes whose path and query strings come from outside; the first
/// byte picks one, the rest is appended to it (a path segment and/or
/// `?query`). Videos are left out: they start a render process.
const ROUTES: &[&str] = &[
    "/api/v1/leaderboards/",
    "/api/v1/submissions",
    "/api/v1/submissions/1/rollouts",
    "/api/v1/submissions/1/rollouts/",
    "/api/v1/compare",
    "/api/v1/methods",
    "/api/v1/submissions/",
    "/api/v1/leaderboards",
    "/tasks/",
    "/submissions",
    "/submissions/1",
    "/submissions/1/rollouts/",
    "/compare",
    "/methods/",
    "/",
    "/plots/tasks/",
    "/plots/submissions/1/",
];

pub fn api_query(data: &[u8]) {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let Ok(rest) = std::str::from_utf8(rest) else {
        return;
    };
    let route = ROUTES[usize::from(pick) % ROUTES.len()];
    let uri = format!("{route}{rest}");
    if rest.contains("/video") {
        return;
    }
    // A target hyper would not parse never reaches the router.
    let Ok(uri) = uri.parse::<axum::http::Uri>() else {
        return;
    };
    let Ok(req) = Request::get(uri.clone()).body(Body::empty()) else {
        return;
    };
    let (status, body) = server().call(req);
    check_answer(
        &uri.to_string(),
        uri.path().starts_with("/api/"),
        status,
        &body,
    );
}
