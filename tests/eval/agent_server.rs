//! A reference-style agent object (its own deques, `reset()`, `predict(obs)`)
//! served unchanged by d3il_client.serve (clients/python) and evaluated with
//! `d3il eval`: one agent state per rollout, reset before its episode, one
//! `predict` per env step with the newest observation.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

const SERVER: &str = r#"
import collections, json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from d3il_client.serve import agent_server
import asyncio

LOG = open(sys.argv[2], "w")
made = [0]

class StandInAgent:
    """Shaped like the D3IL agents: a window deque that starts empty at reset."""
    def __init__(self):
        made[0] += 1
        self.name = made[0]
        self.obs_context = collections.deque(maxlen=5)
        self.resets = 0
        self.calls = 0
    def reset(self):
        self.obs_context.clear()
        self.resets += 1
    def predict(self, state):
        assert state.shape == (20,), state.shape
        self.obs_context.append(state)
        self.calls += 1
        LOG.write(json.dumps({"agent": self.name, "resets": self.resets,
                              "calls": self.calls, "window": len(self.obs_context)}) + "\n")
        LOG.flush()
        return np.array([[0.001, -0.0005, 0.0]], np.float32)   # [1, act_dim] as the reference returns

server = agent_server(lambda: StandInAgent())
asyncio.run(server.run("127.0.0.1", 0, lambda port: print(f"listening on 127.0.0.1:{port}", flush=True)))
"#;

#[test]
fn a_reference_style_agent_is_served_with_one_state_per_rollout() {
    let clients = concat!(env!("CARGO_MANIFEST_DIR"), "/clients/python");
    let dir = std::env::temp_dir().join(format!("d3il-agent-server-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("calls.jsonl");
    let mut server = Command::new("python3")
        .args(["-c", SERVER, clients])
        .arg(&log)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("python3 with numpy, websockets, msgpack");
    let mut line = String::new();
    BufReader::new(server.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let port: u16 = line.trim().rsplit(':').next().unwrap().parse().unwrap();
    let json = dir.join("r.json");
    let run = Command::new(env!("CARGO_BIN_EXE_d3il"))
        .args(["eval", "--task", "aligning", "--protocol", "quick"])
        .args(["--allow-private-endpoints", "--policy"])
        .arg(format!("ws://127.0.0.1:{port}/"))
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    let _ = server.kill();
    let _ = server.wait();
    assert!(
        run.status.success(),
        "d3il eval failed:\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let mut steps: Vec<u64> = r["rollouts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["steps"].as_u64().unwrap())
        .collect();
    assert_eq!(steps.len(), 6);
    let calls: Vec<serde_json::Value> = std::fs::read_to_string(&log)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // Per agent: reset once, then one predict per step with a window growing to 5.
    let mut per_agent: std::collections::BTreeMap<u64, Vec<&serde_json::Value>> =
        Default::default();
    for c in &calls {
        per_agent
            .entry(c["agent"].as_u64().unwrap())
            .or_default()
            .push(c);
    }
    let mut counts: Vec<u64> = vec![];
    for (agent, cs) in &per_agent {
        for (i, c) in cs.iter().enumerate() {
            assert_eq!(c["resets"], 1, "agent {agent}");
            assert_eq!(c["calls"].as_u64().unwrap(), i as u64 + 1, "agent {agent}");
            assert_eq!(
                c["window"].as_u64().unwrap(),
                (i as u64 + 1).min(5),
                "agent {agent}"
            );
        }
        counts.push(cs.len() as u64);
    }
    assert_eq!(per_agent.len(), 6, "one agent state per rollout");
    counts.sort_unstable();
    steps.sort_unstable();
    assert_eq!(counts, steps, "one predict per env step of each rollout");
    std::fs::remove_dir_all(&dir).unwrap();
}
