//! Remote-endpoint frames: a real [`RemotePolicy`] talks to a scripted
//! endpoint on 127.0.0.1 whose one reply is the fuzz input. The first byte
//! picks the reply (`% 4`: the hello, the answer to the spec, to `reset`,
//! to `infer`; the other replies are valid) and, with bit 0x80, sends the
//! bytes raw on the socket instead of as one binary WebSocket frame, so
//! both the WebSocket framing (tungstenite, with the frame-size cap) and
//! the msgpack decoding and field checks (`d3il_policy::wire`, the
//! session) read outside bytes, exactly as in an evaluation.

use crate::assert_described;
use d3il_policy::{Policy, Query, RemotePolicy};
use d3il_protocol::{Limits, ObsType, TaskId, TaskSpec};
use rmpv::Value;
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Mutex, OnceLock};
use std::time::Duration;
use tungstenite::Message;

/// The stage whose reply is fuzzed.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Stage {
    Hello,
    Ready,
    ResetOk,
    Actions,
}

struct Script {
    stage: Stage,
    raw: bool,
    bytes: Vec<u8>,
}

/// The endpoint: a thread that serves one connection per script and says
/// when it is done with it.
struct Endpoint {
    url: String,
    scripts: Sender<Script>,
    done: Receiver<()>,
}

fn endpoint() -> &'static Mutex<Endpoint> {
    static E: OnceLock<Mutex<Endpoint>> = OnceLock::new();
    E.get_or_init(|| {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1");
        let url = format!("ws://{}/", listener.local_addr().expect("local address"));
        let (scripts, rx) = channel::<Script>();
        let (done_tx, done) = channel();
        std::thread::spawn(move || {
            while let Ok(script) = rx.recv() {
                if let Ok((stream, _)) = listener.accept() {
                    serve(stream, &script);
                }
                if done_tx.send(()).is_err() {
                    return;
                }
            }
        });
        Mutex::new(Endpoint { url, scripts, done })
    })
}

const ACT_DIM: usize = 2;
const OBS_DIM: usize = 4;
const BATCH: usize = 2;

fn msg(entries: Vec<(&str, Value)>) -> Vec<u8> {
    d3il_policy::wire::encode(&d3il_policy::wire::map(entries))
}

/// The valid reply of each stage (history 1, horizon 1: actions `[2, 2]`).
fn valid(stage: Stage) -> Vec<u8> {
    match stage {
        Stage::Hello => msg(vec![
            ("type", "hello".into()),
            ("protocol", 1u64.into()),
            ("history", 1u64.into()),
            ("horizon", 1u64.into()),
            ("execute", 1u64.into()),
        ]),
        Stage::Ready => msg(vec![("type", "ready".into())]),
        Stage::ResetOk => msg(vec![("type", "ok".into())]),
        Stage::Actions => msg(vec![
            ("type", "actions".into()),
            ("id", 1u64.into()),
            (
                "actions",
                d3il_policy::wire::encode_f32(&[BATCH, ACT_DIM], &[0.1, -0.2, 0.3, 0.0]),
            ),
        ]),
    }
}

/// The valid replies of every stage (hex, for seeds: `valid_replies`).
pub fn valid_replies() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("hello", valid(Stage::Hello)),
        ("ready", valid(Stage::Ready)),
        ("reset", valid(Stage::ResetOk)),
        ("actions", valid(Stage::Actions)),
    ]
}

fn serve(stream: TcpStream, script: &Script) {
    // Closed with a reset, not left in TIME_WAIT: thousands of connections
    // a second would use up the ephemeral ports.
    abortive_close(&stream);
    let _ = stream.set_read_timeout(Some(Duration::from_secs(5)));
    let Ok(mut ws) = tungstenite::accept(stream) else {
        return;
    };
    for stage in [Stage::Hello, Stage::Ready, Stage::ResetOk, Stage::Actions] {
        // Every reply but the hello answers a request.
        if stage != Stage::Hello && !matches!(ws.read(), Ok(Message::Binary(_))) {
            return;
        }
        if stage == script.stage {
            if script.raw {
                let s = ws.get_mut();
                let _ = s.write_all(&script.bytes);
                let _ = s.shutdown(std::net::Shutdown::Write);
                break;
            }
            if ws
                .send(Message::Binary(script.bytes.clone().into()))
                .is_err()
            {
                return;
            }
        } else if ws.send(Message::Binary(valid(stage).into())).is_err() {
            return;
        }
    }
    // Wait for the client to go (its close, or the end of the stream).
    let s = ws.get_mut();
    let mut sink = [0u8; 4096];
    while matches!(s.read(&mut sink), Ok(n) if n > 0) {}
}

fn abortive_close(stream: &TcpStream) {
    use std::os::fd::AsRawFd;
    let linger = libc::linger {
        l_onoff: 1,
        l_linger: 0,
    };
    // SAFETY: setsockopt on an open socket with a pointer to a local struct
    // of the size passed.
    unsafe {
        libc::setsockopt(
            stream.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_LINGER,
            &linger as *const libc::linger as *const libc::c_void,
            std::mem::size_of::<libc::linger>() as libc::socklen_t,
        );
    }
}

pub fn remote_frame(data: &[u8]) {
    let Some((&pick, bytes)) = data.split_first() else {
        return;
    };
    let stage = [Stage::Hello, Stage::Ready, Stage::ResetOk, Stage::Actions][usize::from(pick & 3)];
    let ep = endpoint().lock().unwrap_or_else(|e| e.into_inner());
    ep.scripts
        .send(Script {
            stage,
            raw: pick & 0x80 != 0,
            bytes: bytes.to_vec(),
        })
        .expect("the endpoint thread runs");
    converse(&ep.url);
    ep.done
        .recv_timeout(Duration::from_secs(10))
        .expect("the endpoint finished its connection");
}

/// What an evaluation does: connect (hello, spec), reset, one batched infer.
fn converse(url: &str) {
    let spec = TaskSpec {
        task: TaskId::Avoiding,
        obs_dim: OBS_DIM,
        act_dim: ACT_DIM,
        max_steps: 250,
        n_behaviours: 24,
    };
    let limits = Limits {
        allow_private_endpoints: true,
        remote_deadline_ms: 3000,
        // The smallest cap the client allows, so oversized frames are reachable.
        remote_frame_bytes: 1024,
        ..Limits::default()
    };
    let mut policy = match RemotePolicy::connect(url, None, &spec, ObsType::State, 0, &limits) {
        Ok(p) => p,
        Err(e) => return assert_described("connect", &e),
    };
    if let Err(e) = policy.reset(&[0, 1]) {
        return assert_described("reset", &e);
    }
    let obs = [0.5f32; BATCH * OBS_DIM];
    match policy.infer(&Query::new(&[0, 1], &[0, 0], &obs)) {
        Ok(chunks) => {
            assert_eq!(chunks.batch, BATCH);
            assert_eq!(
                chunks.data.len(),
                chunks.batch * chunks.horizon * chunks.act_dim
            );
            assert_eq!(chunks.act_dim, ACT_DIM);
        }
        Err(e) => assert_described("infer", &e),
    }
}
