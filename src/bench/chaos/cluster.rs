//! The service the chaos bench runs: PostgreSQL (`d3il_pgtemp`), two front
//! ends and three worker hosts, each process restartable, and the faults
//! injected into them.

use super::exe;
use crate::bench::procs::{children, spawn_ready, Proc};
use anyhow::Context;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Front ends, worker hosts and the shards an evaluation is split into.
pub const FRONT_ENDS: usize = 2;
pub const HOSTS: usize = 3;
const SHARDS: &str = "3";
/// Short leases, so that a killed host's shards are taken over within
/// seconds (heartbeats every third of it).
const LEASE_SECONDS: &str = "6";
/// Sandbox limits of every worker: the hostile model that computes forever
/// runs into the CPU limit after this long.
const LIMITS: [&str; 5] = [
    "--cpu-seconds",
    "10",
    "--wall-seconds",
    "120",
    "--allow-private-endpoints",
];

/// What the fault injector kills.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    FrontEnd,
    Host,
    Worker,
    Database,
}

impl FaultKind {
    pub const ALL: [FaultKind; 4] = [
        FaultKind::FrontEnd,
        FaultKind::Host,
        FaultKind::Worker,
        FaultKind::Database,
    ];

    pub fn label(self) -> &'static str {
        match self {
            FaultKind::FrontEnd => "front end",
            FaultKind::Host => "worker host",
            FaultKind::Worker => "worker process",
            FaultKind::Database => "database",
        }
    }
}

/// One injected fault: what was killed and how long until it ran again.
#[derive(Debug, Clone)]
pub struct Fault {
    pub kind: FaultKind,
    pub what: String,
    pub down: Duration,
}

/// A restartable process of the service.
struct Member {
    name: String,
    proc: Mutex<Option<Proc>>,
}

pub struct Cluster {
    pub url: String,
    /// `--policy-store` of every process (uploads in `policies/`).
    pub store: PathBuf,
    pub token: String,
    /// Front end i listens on `http://127.0.0.1:{ports[i]}`, restarts included.
    pub ports: Vec<u16>,
    dir: PathBuf,
    fronts: Vec<Member>,
    hosts: Vec<Member>,
}

/// A log file of `dir`, appended to across restarts.
fn log(dir: &Path, name: &str) -> anyhow::Result<std::fs::File> {
    let path = dir.join(format!("{name}.log"));
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))
}

impl Cluster {
    /// A fresh database on the process's PostgreSQL, a token, both front ends
    /// and every worker host, each ready.
    pub fn start(dir: &Path) -> anyhow::Result<Cluster> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let url = d3il_pgtemp::fresh_database();
        durable_commits(&url)?;
        let store = dir.join("policy-store");
        let out = Command::new(exe()?)
            .args([
                "token",
                "create",
                "--name",
                "chaos",
                "--db",
                &url,
                "--policy-store",
            ])
            .arg(&store)
            .output()
            .context("running d3il token create")?;
        anyhow::ensure!(
            out.status.success(),
            "d3il token create failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let token = String::from_utf8(out.stdout)?.trim().to_string();
        let mut c = Cluster {
            url,
            store,
            token,
            ports: (0..FRONT_ENDS).map(|_| d3il_pgtemp::free_port()).collect(),
            dir: dir.to_path_buf(),
            fronts: vec![],
            hosts: vec![],
        };
        for i in 0..FRONT_ENDS {
            let name = format!("front-{i}");
            let proc = c.start_front(i, &name)?;
            c.fronts.push(Member {
                name,
                proc: Mutex::new(Some(proc)),
            });
        }
        for i in 0..HOSTS {
            let name = format!("host-{i}");
            let proc = c.start_host(&name)?;
            c.hosts.push(Member {
                name,
                proc: Mutex::new(Some(proc)),
            });
        }
        Ok(c)
    }

    /// Front end 0 dry-runs every upload at submission (a hostile model is
    /// refused there); front end 1 queues uploads without (it fails in its
    /// evaluation): both paths are under load.
    pub fn dry_runs(front: usize) -> bool {
        front == 0
    }

    fn start_front(&self, i: usize, name: &str) -> anyhow::Result<Proc> {
        let mut cmd = Command::new(exe()?);
        cmd.args(["serve", "--db", &self.url, "--policy-store"])
            .arg(&self.store)
            .args(["--workers", "0", "--shards", SHARDS, "--bind"])
            .arg(format!("127.0.0.1:{}", self.ports[i]))
            .args(["--no-verify", "--fidelity", "off", "--zoo", "none"])
            .args(["--rate-limit", "100000", "--anonymous-rate-limit", "100000"])
            // One token submits the whole load: no submission quota.
            .args([
                "--quota-per-day",
                "0",
                "--quota-total",
                "0",
                "--quota-concurrent",
                "0",
            ])
            .args(LIMITS)
            .stderr(log(&self.dir, name)?);
        if !Self::dry_runs(i) {
            cmd.arg("--no-upload-dry-run");
        }
        Ok(spawn_ready(cmd, "listening on ", &format!("d3il serve ({name})"))?.0)
    }

    fn start_host(&self, name: &str) -> anyhow::Result<Proc> {
        let mut cmd = Command::new(exe()?);
        cmd.args(["workers", "--db", &self.url, "--policy-store"])
            .arg(&self.store)
            .args(["--workers", "1", "--lease-seconds", LEASE_SECONDS])
            .args(LIMITS)
            .stderr(log(&self.dir, name)?);
        Ok(spawn_ready(cmd, "worker host ready", &format!("d3il workers ({name})"))?.0)
    }

    /// Starts a killed member again, retrying while it cannot start (the
    /// database may be down at that moment).
    fn restart(&self, member: &Member, front: Option<usize>) -> anyhow::Result<()> {
        let deadline = Instant::now() + Duration::from_secs(120);
        loop {
            let started = match front {
                Some(i) => self.start_front(i, &member.name),
                None => self.start_host(&member.name),
            };
            match started {
                Ok(p) => {
                    *lock(&member.proc) = Some(p);
                    return Ok(());
                }
                Err(e) if Instant::now() > deadline => {
                    return Err(e.context(format!("{} did not start again", member.name)))
                }
                Err(_) => std::thread::sleep(Duration::from_millis(500)),
            }
        }
    }

    /// Kills one member of `kind` chosen with `pick` (SIGKILL) and starts it
    /// again; `None` when there is nothing of that kind to kill (no worker
    /// process runs right now).
    pub fn inject(
        &self,
        kind: FaultKind,
        pick: &mut dyn FnMut(usize) -> usize,
    ) -> anyhow::Result<Option<Fault>> {
        let t0 = Instant::now();
        let what = match kind {
            FaultKind::FrontEnd | FaultKind::Host => {
                let (members, front) = if kind == FaultKind::FrontEnd {
                    let i = pick(self.fronts.len());
                    (&self.fronts[i], Some(i))
                } else {
                    (&self.hosts[pick(self.hosts.len())], None)
                };
                if let Some(mut p) = lock(&members.proc).take() {
                    p.kill();
                }
                // A moment down, as a crashed process that is restarted.
                std::thread::sleep(Duration::from_millis(300));
                self.restart(members, front)?;
                members.name.clone()
            }
            FaultKind::Worker => {
                let workers = self.worker_processes();
                if workers.is_empty() {
                    return Ok(None);
                }
                let (host, pid) = &workers[pick(workers.len())];
                // A sandboxed worker is the leader of its own process group.
                let _ = Command::new("kill")
                    .args(["-KILL", &pid.to_string()])
                    .stderr(Stdio::null())
                    .status();
                format!("d3il worker {pid} of {host}")
            }
            FaultKind::Database => {
                let pg = d3il_pgtemp::cluster();
                pg.kill();
                std::thread::sleep(Duration::from_millis(500));
                pg.restart().map_err(anyhow::Error::msg)?;
                "PostgreSQL".to_string()
            }
        };
        Ok(Some(Fault {
            kind,
            what,
            down: t0.elapsed(),
        }))
    }

    /// The `d3il worker` processes of every host: (host, pid).
    fn worker_processes(&self) -> Vec<(String, u32)> {
        let mut out = vec![];
        for h in &self.hosts {
            let Some(pid) = lock(&h.proc).as_ref().map(Proc::pid) else {
                continue;
            };
            for child in children(pid) {
                let cmdline = std::fs::read(format!("/proc/{child}/cmdline")).unwrap_or_default();
                if cmdline.split(|&b| b == 0).any(|a| a == b"worker") {
                    out.push((h.name.clone(), child));
                }
            }
        }
        out
    }

    /// Job ids each host's log says it started (a shard taken over or
    /// retried is started again), over every restart of every host.
    pub fn started_jobs(&self) -> Vec<i64> {
        self.host_log_lines()
            .iter()
            .filter(|l| l.contains(" started on "))
            .filter_map(|l| job_id(l))
            .collect()
    }

    /// Per job id, how many of its attempts ended with its worker killed
    /// from outside (the injector's SIGKILL), from the hosts' logs.
    pub fn outside_kills(&self) -> HashMap<i64, usize> {
        let mut kills = HashMap::new();
        for line in self.host_log_lines() {
            if line.contains(" failed (Crashed: ") && line.contains("killed from outside") {
                if let Some(id) = job_id(&line) {
                    *kills.entry(id).or_default() += 1;
                }
            }
        }
        kills
    }

    fn host_log_lines(&self) -> Vec<String> {
        self.hosts
            .iter()
            .flat_map(|h| {
                std::fs::read_to_string(self.dir.join(format!("{}.log", h.name)))
                    .unwrap_or_default()
                    .lines()
                    .map(str::to_string)
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    /// Whether every member still runs (none exited on its own).
    pub fn all_running(&self) -> Vec<String> {
        self.fronts
            .iter()
            .chain(&self.hosts)
            .filter(|m| !lock(&m.proc).as_mut().is_some_and(Proc::running))
            .map(|m| m.name.clone())
            .collect()
    }
}

/// PostgreSQL's default `synchronous_commit = on` for the run's database.
/// The throw-away cluster turns it off for the tests' speed, and then a
/// commit is acknowledged before its WAL leaves the server's memory: a
/// killed server loses the last fraction of a second of commits, an
/// accepted submission among them (the first full run of this bench saw one
/// vanish). A service's database keeps the default; so does this bench.
fn durable_commits(url: &str) -> anyhow::Result<()> {
    use d3il_server::ops::sqlx;
    let name = url.rsplit('/').next().unwrap_or_default();
    anyhow::ensure!(
        !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'),
        "unexpected database name in {url}"
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let pool = sqlx::PgPool::connect(url).await?;
        let sql = format!("ALTER DATABASE {name} SET synchronous_commit = on");
        sqlx::query(sqlx::AssertSqlSafe(sql)).execute(&pool).await?;
        pool.close().await;
        anyhow::Ok(())
    })
}

/// The job id of a pool log line (`… job 12 (submission 4, …) …`).
fn job_id(line: &str) -> Option<i64> {
    let rest = &line[line.find("job ")? + 4..];
    rest.split_whitespace().next()?.parse().ok()
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// `faults F: front end a, worker host b, worker process c, database d; down for … s at most`.
pub fn fault_summary(faults: &[Fault]) -> String {
    let by_kind: Vec<String> = FaultKind::ALL
        .iter()
        .map(|k| {
            let n = faults.iter().filter(|f| f.kind == *k).count();
            format!("{} {n}", k.label())
        })
        .collect();
    let longest = faults
        .iter()
        .filter(|f| f.kind != FaultKind::Worker)
        .map(|f| f.down.as_secs_f64())
        .fold(0.0, f64::max);
    format!(
        "faults {}: {}; a killed front end, host or database was back within {longest:.1} s",
        faults.len(),
        by_kind.join(", ")
    )
}
