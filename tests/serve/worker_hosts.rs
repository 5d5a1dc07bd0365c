//! Several machines on one PostgreSQL queue (issue 19): a front end
//! (`d3il serve --workers 0 --shards 3`) takes submissions, worker hosts
//! (`d3il workers`) run their shards, and the last shard merges. Everything is
//! real: a throw-away PostgreSQL cluster, the `d3il` binary, the sandboxed
//! `d3il worker`, the ONNX fixture assets/fixtures/aligning_mlp.onnx under the
//! quick protocol (3 initial states x 2 rollouts, so 3 shards of one initial
//! state each).

use crate::{D3IL, EXE};
use d3il_test_support::server::*;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

/// A `d3il workers` process; its log (stderr) goes to a file.
struct Host {
    child: Child,
    log: PathBuf,
}

impl Host {
    fn start(url: &str, store: &Path, log: PathBuf) -> Host {
        let mut child = Command::new(EXE)
            .args(["workers", "--db", url, "--policy-store"])
            .arg(store)
            .args(["--workers", "1", "--lease-seconds", "3"])
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log).expect("host log"))
            .spawn()
            .expect("start d3il workers");
        wait_for_line(&mut child, "worker host ready", "d3il workers");
        Host { child, log }
    }

    /// Job (shard) ids this host started, from its log.
    fn started(&self) -> Vec<i64> {
        std::fs::read_to_string(&self.log)
            .unwrap_or_default()
            .lines()
            .filter(|l| l.contains(" started on "))
            .filter_map(|l| {
                let rest = &l[l.find("job ")? + 4..];
                rest.split_whitespace().next()?.parse().ok()
            })
            .collect()
    }

    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Host {
    fn drop(&mut self) {
        self.kill();
        if std::thread::panicking() {
            let log = std::fs::read_to_string(&self.log).unwrap_or_default();
            let tail: Vec<&str> = log.lines().rev().take(40).collect();
            eprintln!("--- {} (last lines) ---", self.log.display());
            for l in tail.iter().rev() {
                eprintln!("{l}");
            }
        }
    }
}

struct Cluster {
    url: String,
    store: PathBuf,
    dir: TempDir,
    token: String,
    front: TestServer,
}

impl Cluster {
    fn start(tag: &str) -> Cluster {
        let dir = TempDir::new(tag);
        let url = d3il_test_support::pg::fresh_database();
        let store = dir.path().join("policy-store");
        let db_args = [
            "--db",
            url.as_str(),
            "--policy-store",
            store.to_str().unwrap(),
        ];
        let token = D3IL.create_token_on("hosts-tester", &db_args);
        let mut front_args = db_args[2..].to_vec();
        front_args.extend(["--workers", "0", "--shards", "3", "--no-upload-dry-run"]);
        let front = D3IL.serve_on(url.as_ref(), &front_args);
        Cluster {
            url,
            store,
            dir,
            token,
            front,
        }
    }

    fn host(&self, name: &str) -> Host {
        Host::start(
            &self.url,
            &self.store,
            self.dir.path().join(format!("{name}.log")),
        )
    }

    fn submit(&self, seed: u32) -> i64 {
        let manifest = std::fs::read_to_string(fixture("aligning_mlp.json")).unwrap();
        let created = self
            .front
            .client(Some(&self.token))
            .submit(
                &[
                    ("method", "Sharded-MLP".to_string()),
                    ("task", "aligning".to_string()),
                    ("training_seed", seed.to_string()),
                    ("protocol", "quick".to_string()),
                    ("manifest", manifest),
                ],
                Some(&fixture("aligning_mlp.onnx")),
            )
            .expect("submission accepted");
        created["id"].as_i64().unwrap()
    }

    fn wait(&self, id: i64) -> Value {
        let done = self
            .front
            .client(Some(&self.token))
            .wait(id, Duration::from_secs(600), |_| {})
            .expect("the sharded job finishes");
        assert_eq!(done["status"], "completed", "{done}");
        done
    }

    /// (id, submission, shard index, state, attempts) of every job row.
    fn shards(&self) -> Vec<(i64, i64, i64, String, i64)> {
        let url = self.url.clone();
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
            .block_on(async move {
                let pool = sqlx::PgPool::connect(&url).await.unwrap();
                sqlx::query_as(
                    "SELECT id, submission_id, shard_index, state, attempts FROM jobs ORDER BY id",
                )
                .fetch_all(&pool)
                .await
                .unwrap()
            })
    }
}

#[test]
fn two_hosts_share_one_queue_run_each_shard_once_and_merge_bit_for_bit() {
    let c = Cluster::start("hosts-share");
    let a = c.host("a");
    let b = c.host("b");
    let ids = [c.submit(0), c.submit(1)];
    let done: Vec<Value> = ids.iter().map(|&id| c.wait(id)).collect();

    let shards = c.shards();
    assert_eq!(shards.len(), 6, "two submissions of 3 shards: {shards:?}");
    for (id, sub, index, state, attempts) in &shards {
        assert_eq!(state, "done", "job {id} (submission {sub}, shard {index})");
        assert_eq!(*attempts, 1, "job {id} ran once");
    }
    // Every shard was started exactly once over both hosts.
    let mut started: Vec<i64> = a.started().into_iter().chain(b.started()).collect();
    started.sort();
    let all: Vec<i64> = shards.iter().map(|s| s.0).collect();
    assert_eq!(
        started,
        all,
        "host a: {:?}, host b: {:?}",
        a.started(),
        b.started()
    );

    for (seed, d) in done.iter().enumerate() {
        let plain = D3IL.plain_eval(c.dir.path(), &fixture("aligning_mlp.onnx"), seed as u32);
        assert_same_result(d, &plain);
        // The hosts record the build that evaluated, with the drift
        // canary's fingerprint, as `d3il eval` does (they recorded
        // `unknown` and no fingerprint before `d3il bench chaos` compared
        // whole manifests).
        assert_eq!(
            d["result"]["protocol_manifest"]["build"], plain["manifest"]["build"],
            "{d}"
        );
    }
}

#[test]
fn a_host_killed_mid_shard_loses_only_its_lease_and_another_finishes() {
    let c = Cluster::start("hosts-kill");
    let mut a = c.host("a");
    let id = c.submit(0);
    // Wait until host a runs a shard (its worker reported progress), then
    // kill it: the sandboxed worker dies with it (PR_SET_PDEATHSIG).
    let client = c.front.client(Some(&c.token));
    wait_for(Duration::from_secs(120), || {
        let v = client.submission(id).ok()?;
        (v["status"] == "running" && v["progress"]["rollouts_total"].as_i64()? > 0).then_some(())
    })
    .expect("host a started a shard");
    a.kill();
    let killed: Vec<i64> = c
        .shards()
        .into_iter()
        .filter(|s| s.3 == "leased")
        .map(|s| s.0)
        .collect();
    assert!(!killed.is_empty(), "a shard was leased when host a died");
    // Host b takes over once the dead host's lease (3 s) has expired.
    let b = c.host("b");
    let done = c.wait(id);
    for (job, _, _, state, attempts) in c.shards() {
        assert_eq!(state, "done");
        assert_eq!(
            attempts, 1,
            "job {job}: taking over a dead host's lease is not a new attempt"
        );
    }
    for job in &killed {
        assert!(
            b.started().contains(job),
            "host b finished job {job} of the dead host: {:?}",
            b.started()
        );
    }
    assert_same_result(
        &done,
        &D3IL.plain_eval(c.dir.path(), &fixture("aligning_mlp.onnx"), 0),
    );
}
