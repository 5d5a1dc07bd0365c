//! The submission stream of the chaos bench: what is sent, to which front
//! end, and what each request was answered.

use super::cluster::{Cluster, FRONT_ENDS};
use crate::bench::procs::{spawn_ready, Proc};
use anyhow::Context;
use d3il_server::client::{reqwest, Client, ClientError};
use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Good ONNX fixtures (assets/fixtures): Aligning ones run in 3 shards,
/// Avoiding ones in one (it has a single initial state); the `noise` ones are
/// stochastic, so their numbers depend on the seed.
const GOOD: [&str; 5] = [
    "aligning_mlp",
    "aligning_mlp_noise",
    "avoiding_path",
    "avoiding_noise",
    "avoiding_k5_h3",
];

/// Hostile fixtures (all for Avoiding); `hostile_endless` only when the
/// plan allows its CPU-limit run.
const HOSTILE: [&str; 11] = [
    "hostile_truncated",
    "hostile_garbage",
    "hostile_nan",
    "hostile_huge_initializer",
    "hostile_wrong_act_dim",
    "hostile_wrong_obs_dim",
    "hostile_external_data",
    "hostile_random_op",
    "hostile_tile_bomb",
    "hostile_mixes_rows",
    "hostile_endless",
];

/// Training seeds (also the evaluator's seeds): a few, so that the plain
/// evaluations the results are compared with are shared.
const SEEDS: u32 = 3;

/// The remote endpoint the remote submissions name: the reference
/// protocol's test server (`d3il_client.serve.testing --mode ok`, the
/// Avoiding demo policy) on 127.0.0.1.
pub struct Endpoint {
    _proc: Proc,
    pub url: String,
}

impl Endpoint {
    pub fn start() -> anyhow::Result<Endpoint> {
        let clients = crate::common::assets_dir().join("../clients/python");
        let mut cmd = Command::new("python3");
        cmd.args(["-m", "d3il_client.serve.testing", "--mode", "ok"])
            .env("PYTHONPATH", &clients)
            .stdin(Stdio::null())
            .stderr(Stdio::null());
        let (proc, line) = spawn_ready(cmd, "listening on ", "the remote policy endpoint").context(
            "the remote endpoint needs python3 with numpy, websockets and msgpack (pip install './clients/python[serve]')",
        )?;
        let addr = line["listening on ".len()..].trim();
        Ok(Endpoint {
            _proc: proc,
            url: format!("ws://{addr}/"),
        })
    }
}

/// A small deterministic generator (SplitMix64): the stream and the faults
/// are the same on every run.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in 0..n (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    /// `mean` scaled by a factor uniform in [0.5, 1.5).
    pub fn around(&mut self, mean: Duration) -> Duration {
        mean.mul_f64(0.5 + (self.next() % 1000) as f64 / 1000.0)
    }
}

/// What a request sends.
#[derive(Debug, Clone, PartialEq)]
pub enum Kind {
    /// A good ONNX fixture: must complete with the plain evaluation's numbers.
    Good(&'static str),
    /// The remote endpoint: must complete likewise.
    Remote,
    /// A hostile fixture: refused at submission, or failed with a reason.
    Hostile(&'static str),
    /// The method and seed of an accepted good submission again: refused.
    Duplicate { fixture: &'static str },
    /// An upload whose body stops half-way: never stored.
    CutOff,
}

impl Kind {
    pub fn label(&self) -> &'static str {
        match self {
            Kind::Good(_) => "good ONNX",
            Kind::Remote => "remote endpoint",
            Kind::Hostile(_) => "hostile ONNX",
            Kind::Duplicate { .. } => "duplicate",
            Kind::CutOff => "cut-off upload",
        }
    }

    /// The policy of a good or remote submission, as the plain evaluation
    /// names it.
    pub fn policy(&self) -> Option<&'static str> {
        match self {
            Kind::Good(f) => Some(f),
            Kind::Remote => Some("remote"),
            _ => None,
        }
    }
}

/// One request and its answer.
#[derive(Debug, Clone)]
pub struct Sent {
    pub n: usize,
    pub kind: Kind,
    /// Method name (unique per request, except for duplicates).
    pub method: String,
    pub seed: u32,
    pub front: usize,
    pub answer: Answer,
    /// When the request started.
    pub at: Instant,
}

#[derive(Debug, Clone)]
pub enum Answer {
    Accepted(i64),
    Refused {
        status: u16,
        message: String,
    },
    /// No front end took the connection.
    FrontDown,
    /// The request broke after it was sent: it may or may not be stored.
    Unanswered(String),
    /// The cut-off upload was sent (and the connection closed).
    CutOff,
}

/// Picks what request `n` sends (`endless`: the CPU-limit fixture may be
/// among the hostile ones).
pub fn choose(rng: &mut Rng, endless: bool) -> (Kind, u32) {
    let seed = rng.below(SEEDS as usize) as u32;
    let hostile = if endless {
        HOSTILE.len()
    } else {
        HOSTILE.len() - 1
    };
    let kind = match rng.below(20) {
        0..=8 => Kind::Good(GOOD[rng.below(GOOD.len())]),
        9..=10 => Kind::Remote,
        11..=13 => Kind::Hostile(HOSTILE[rng.below(hostile)]),
        14..=16 => Kind::Duplicate { fixture: "" },
        _ => Kind::CutOff,
    };
    (kind, seed)
}

fn fixture(stem: &str, ext: &str) -> PathBuf {
    crate::common::assets_dir()
        .join("fixtures")
        .join(format!("{stem}.{ext}"))
}

fn task_of(stem: &str) -> &'static str {
    if stem.starts_with("aligning") {
        "aligning"
    } else {
        "avoiding"
    }
}

/// Accepted good submissions, which duplicates repeat: (method, seed, fixture).
pub type Accepted = Mutex<Vec<(String, u32, &'static str)>>;

/// Sends request `n` to front end `front` (the other one when that one
/// refuses the connection).
#[allow(clippy::too_many_arguments)]
pub fn send(
    cluster: &Cluster,
    phase: &str,
    n: usize,
    mut kind: Kind,
    seed: u32,
    front: usize,
    endpoint: &str,
    accepted: &Accepted,
) -> Sent {
    let at = Instant::now();
    let mut method = format!("Chaos-{phase}-{n}");
    let mut seed = seed;
    if let Kind::Duplicate { .. } = kind {
        let earlier = accepted.lock().unwrap_or_else(|p| p.into_inner());
        match earlier.get(n % earlier.len().max(1)) {
            Some((m, s, f)) => {
                method = m.clone();
                seed = *s;
                kind = Kind::Duplicate { fixture: f };
            }
            None => kind = Kind::Good(GOOD[n % GOOD.len()]),
        }
    }
    let mut answer = Answer::FrontDown;
    let mut used = front;
    for attempt in 0..FRONT_ENDS {
        used = (front + attempt) % FRONT_ENDS;
        answer = if kind == Kind::CutOff {
            cut_off(cluster, used, &method, n)
        } else {
            submit(cluster, used, &kind, &method, seed, endpoint)
        };
        if !matches!(answer, Answer::FrontDown) {
            break;
        }
    }
    if let (Answer::Accepted(_), Kind::Good(f)) = (&answer, &kind) {
        accepted
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push((method.clone(), seed, f));
    }
    Sent {
        n,
        kind,
        method,
        seed,
        front: used,
        answer,
        at,
    }
}

fn submit(
    cluster: &Cluster,
    front: usize,
    kind: &Kind,
    method: &str,
    seed: u32,
    endpoint: &str,
) -> Answer {
    let base = format!("http://127.0.0.1:{}", cluster.ports[front]);
    let client = match Client::new(&base, Some(cluster.token.clone())) {
        Ok(c) => c,
        Err(e) => return Answer::Unanswered(e.to_string()),
    };
    let mut fields = vec![
        ("method", method.to_string()),
        ("training_seed", seed.to_string()),
        ("protocol", "quick".to_string()),
    ];
    let onnx = match kind {
        Kind::Remote => {
            fields.push(("task", "avoiding".into()));
            fields.push(("endpoint_url", endpoint.to_string()));
            None
        }
        Kind::Good(f) | Kind::Hostile(f) | Kind::Duplicate { fixture: f } => {
            fields.push(("task", task_of(f).into()));
            let manifest = std::fs::read_to_string(fixture(f, "json")).unwrap_or_default();
            fields.push(("manifest", manifest));
            Some(fixture(f, "onnx"))
        }
        Kind::CutOff => None,
    };
    match client.submit(&fields, onnx.as_deref()) {
        Ok(v) => match v["id"].as_i64() {
            Some(id) => Answer::Accepted(id),
            None => Answer::Unanswered(format!("an answer without an id: {v}")),
        },
        Err(ClientError::Api {
            status, message, ..
        }) if status < 500 => Answer::Refused { status, message },
        Err(ClientError::Http(e)) if is_refused_connection(&e) => Answer::FrontDown,
        Err(e) => Answer::Unanswered(e.to_string()),
    }
}

fn is_refused_connection(e: &reqwest::Error) -> bool {
    e.is_connect()
}

/// A multipart upload of `aligning_mlp.onnx` whose body stops half-way
/// through the file (the declared length is the whole body's), after which
/// the connection is closed.
fn cut_off(cluster: &Cluster, front: usize, method: &str, n: usize) -> Answer {
    let onnx = std::fs::read(fixture("aligning_mlp", "onnx")).unwrap_or_default();
    let manifest = std::fs::read_to_string(fixture("aligning_mlp", "json")).unwrap_or_default();
    let boundary = "chaos-cut-off-boundary";
    let mut body = Vec::new();
    for (k, v) in [
        ("method", method),
        ("task", "aligning"),
        ("training_seed", "0"),
        ("protocol", "quick"),
        ("manifest", manifest.as_str()),
    ] {
        body.extend(
            format!("--{boundary}\r\nContent-Disposition: form-data; name=\"{k}\"\r\n\r\n{v}\r\n")
                .as_bytes(),
        );
    }
    body.extend(
        format!(
            "--{boundary}\r\nContent-Disposition: form-data; name=\"onnx\"; filename=\"policy.onnx\"\r\n\
             Content-Type: application/octet-stream\r\n\r\n"
        )
        .as_bytes(),
    );
    let file_start = body.len();
    body.extend(&onnx);
    body.extend(format!("\r\n--{boundary}--\r\n").as_bytes());
    // Somewhere in the file's first nine tenths.
    let cut = file_start + (onnx.len() / 10) * (1 + n % 9);
    let head = format!(
        "POST /api/v1/submissions HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {}\r\n\
         Content-Type: multipart/form-data; boundary={boundary}\r\nContent-Length: {}\r\n\r\n",
        cluster.token,
        body.len()
    );
    let addr = std::net::SocketAddr::from(([127, 0, 0, 1], cluster.ports[front]));
    let Ok(mut s) = std::net::TcpStream::connect_timeout(&addr, Duration::from_secs(5)) else {
        return Answer::FrontDown;
    };
    let _ = s.write_all(head.as_bytes());
    let _ = s.write_all(&body[..cut]);
    let _ = s.flush();
    // Time for the front end to stream what came into its temporary file.
    std::thread::sleep(Duration::from_millis(300));
    drop(s);
    Answer::CutOff
}
