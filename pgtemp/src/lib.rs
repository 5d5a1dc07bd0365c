//! A throw-away PostgreSQL: one cluster per process (tests, `d3il bench scale`),
//! made with Debian's `initdb` in a temporary directory and started on a free
//! port of 127.0.0.1, trust authentication, no Unix socket. As root (where
//! `initdb` refuses to run) the cluster belongs to `nobody`. Each test takes
//! a fresh database of its own ([`fresh_database`]).
//!
//! The server process is a child of a thread that never ends and is asked to
//! die with it (`PR_SET_PDEATHSIG`), so it goes when the test process does;
//! data directories of test processes that are gone are removed at the next
//! start.
//!
//! Used by the store tests (through `d3il-test-support`) and by
//! `d3il bench scale` and `d3il bench chaos`, which need a PostgreSQL queue
//! and have none given; the chaos bench kills the server ([`PgCluster::kill`])
//! and starts it again on the same data directory and port
//! ([`PgCluster::restart`]).

use std::net::TcpListener;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// The running test cluster.
pub struct PgCluster {
    pub port: u16,
    bin: PathBuf,
    /// Owner of the files (`nobody` when the tests run as root).
    ids: Option<(u32, u32)>,
    /// The cluster's directory (data directory `data`, log `server.log`).
    dir: PathBuf,
    /// Process id of the running postmaster (0 while none runs).
    pid: AtomicU32,
}

const PREFIX: &str = "d3il-pg-";
const USER: &str = "d3il";

/// Debian's PostgreSQL binaries (`/usr/lib/postgresql/<version>/bin`), newest
/// version first.
fn bin_dir() -> PathBuf {
    let mut dirs: Vec<(u32, PathBuf)> = std::fs::read_dir("/usr/lib/postgresql")
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let v = e.file_name().to_string_lossy().parse::<u32>().ok()?;
            let bin = e.path().join("bin");
            bin.join("initdb").exists().then_some((v, bin))
        })
        .collect();
    dirs.sort();
    dirs.pop().map(|(_, b)| b).unwrap_or_else(|| {
        panic!(
            "PostgreSQL is not installed (no /usr/lib/postgresql/*/bin/initdb): the store tests run on a real \
             PostgreSQL; `./dev test` installs Debian's `postgresql` package"
        )
    })
}

/// Removes data directories left by test processes that have ended.
fn remove_stale() {
    for e in std::fs::read_dir(std::env::temp_dir())
        .into_iter()
        .flatten()
        .flatten()
    {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some(pid) = name
            .strip_prefix(PREFIX)
            .and_then(|p| p.parse::<u32>().ok())
        {
            if !Path::new(&format!("/proc/{pid}")).exists() {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
}

/// A port of 127.0.0.1 that was free a moment ago (bound, then released).
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port on 127.0.0.1")
}

impl PgCluster {
    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(self.bin.join(program));
        if let Some((uid, gid)) = self.ids {
            c.uid(uid).gid(gid);
        }
        c
    }

    fn start() -> PgCluster {
        remove_stale();
        let bin = bin_dir();
        // SAFETY: geteuid has no preconditions.
        let root = unsafe { libc::geteuid() } == 0;
        let ids = root.then_some((65534, 65534));
        let dir = std::env::temp_dir().join(format!("{PREFIX}{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("create the PostgreSQL test directory");
        if let Some((uid, gid)) = ids {
            std::os::unix::fs::chown(&dir, Some(uid), Some(gid))
                .expect("chown the test directory to nobody");
        }
        let data = dir.join("data");
        let cluster = PgCluster {
            port: free_port(),
            bin,
            ids,
            dir: dir.clone(),
            pid: AtomicU32::new(0),
        };
        let out = cluster
            .command("initdb")
            .arg("-D")
            .arg(&data)
            .args([
                "-U",
                USER,
                "--auth=trust",
                "--no-sync",
                "-E",
                "UTF8",
                "--locale=C",
            ])
            .current_dir(&dir)
            .output()
            .expect("run initdb");
        assert!(
            out.status.success(),
            "initdb failed: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        cluster
            .spawn_server()
            .unwrap_or_else(|e| panic!("start postgres: {e}"));
        cluster
            .wait_ready(Duration::from_secs(60))
            .unwrap_or_else(|e| panic!("{e}"));
        cluster
    }

    /// Starts the postmaster on the cluster's data directory and port.
    fn spawn_server(&self) -> std::io::Result<()> {
        let mut server = self.command("postgres");
        server
            .arg("-D")
            .arg(self.dir.join("data"))
            .args(["-p", &self.port.to_string()])
            .args([
                "-c",
                "listen_addresses=127.0.0.1",
                "-c",
                "unix_socket_directories=",
            ])
            .args([
                "-c",
                "fsync=off",
                "-c",
                "synchronous_commit=off",
                "-c",
                "full_page_writes=off",
            ])
            .args(["-c", "max_connections=300"])
            .current_dir(&self.dir)
            .stdout(std::process::Stdio::null())
            .stderr(
                std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(self.dir.join("server.log"))?,
            );
        // SAFETY: prctl is async-signal-safe; it only sets this child's
        // parent-death signal.
        unsafe {
            server.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
                Ok(())
            });
        }
        // The parent-death signal follows the spawning *thread*: spawn from
        // one that lives as long as the server (it waits for it).
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || match server.spawn() {
            Ok(mut child) => {
                let _ = tx.send(Ok(child.id()));
                let _ = child.wait();
            }
            Err(e) => {
                let _ = tx.send(Err(e));
            }
        });
        let pid = rx.recv().map_err(std::io::Error::other)??;
        self.pid.store(pid, Ordering::SeqCst);
        Ok(())
    }

    /// Waits until the server accepts connections.
    fn wait_ready(&self, timeout: Duration) -> Result<(), String> {
        let deadline = Instant::now() + timeout;
        loop {
            let ready = self
                .command("pg_isready")
                .args(["-h", "127.0.0.1", "-p", &self.port.to_string(), "-U", USER])
                .output()
                .map(|o| o.status.success())
                .unwrap_or(false);
            if ready {
                return Ok(());
            }
            let pid = self.pid.load(Ordering::SeqCst);
            if pid == 0 || !Path::new(&format!("/proc/{pid}")).exists() {
                return Err(format!(
                    "PostgreSQL exited while starting; see {}",
                    self.dir.join("server.log").display()
                ));
            }
            if Instant::now() >= deadline {
                return Err(format!(
                    "PostgreSQL did not start within {timeout:?}; see {}",
                    self.dir.join("server.log").display()
                ));
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// SIGKILL to the postmaster and every process it started, at once: the
    /// database machine crashing, as far as its processes go. Open
    /// connections break; what was committed is in the data directory.
    pub fn kill(&self) {
        let pid = self.pid.swap(0, Ordering::SeqCst);
        if pid == 0 {
            return;
        }
        let pid = pid as i32;
        // Stopped first, so that it starts no backend between the listing of
        // its children and their end.
        // SAFETY: kill has no memory-safety preconditions.
        unsafe { libc::kill(pid, libc::SIGSTOP) };
        for child in children(pid as u32) {
            // SAFETY: as above.
            unsafe { libc::kill(child as i32, libc::SIGKILL) };
        }
        // SAFETY: as above.
        unsafe { libc::kill(pid, libc::SIGKILL) };
    }

    /// Starts the server again on the same data directory and port after
    /// [`PgCluster::kill`] (PostgreSQL runs its crash recovery) and waits
    /// until it accepts connections. Retries while the killed processes
    /// still hold the old shared memory.
    pub fn restart(&self) -> Result<(), String> {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            self.spawn_server()
                .map_err(|e| format!("start postgres: {e}"))?;
            match self.wait_ready(Duration::from_secs(30)) {
                Ok(()) => return Ok(()),
                Err(e) if Instant::now() >= deadline => return Err(e),
                Err(_) => std::thread::sleep(Duration::from_millis(300)),
            }
        }
    }

    /// Process id of the running postmaster, if one runs.
    pub fn pid(&self) -> Option<u32> {
        Some(self.pid.load(Ordering::SeqCst)).filter(|&p| p != 0)
    }

    /// A URL for database `name` of this cluster.
    pub fn url(&self, name: &str) -> String {
        format!("postgres://{USER}@127.0.0.1:{}/{name}", self.port)
    }
}

/// Child processes of `pid` (every thread's children, from `/proc`); also
/// what the benches and tests that kill a server's workers use.
pub fn children(pid: u32) -> Vec<u32> {
    let mut out = vec![];
    for t in std::fs::read_dir(format!("/proc/{pid}/task"))
        .into_iter()
        .flatten()
        .flatten()
    {
        if let Ok(s) = std::fs::read_to_string(t.path().join("children")) {
            out.extend(s.split_whitespace().filter_map(|p| p.parse::<u32>().ok()));
        }
    }
    out
}

/// The process's test cluster, started on first use.
pub fn cluster() -> &'static PgCluster {
    static CLUSTER: OnceLock<PgCluster> = OnceLock::new();
    CLUSTER.get_or_init(PgCluster::start)
}

/// A new, empty database on the test cluster; returns its URL.
pub fn fresh_database() -> String {
    static N: AtomicU64 = AtomicU64::new(0);
    let c = cluster();
    let name = format!(
        "t{}_{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    );
    let out = c
        .command("createdb")
        .args([
            "-h",
            "127.0.0.1",
            "-p",
            &c.port.to_string(),
            "-U",
            USER,
            &name,
        ])
        .output()
        .expect("run createdb");
    assert!(
        out.status.success(),
        "createdb {name} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    c.url(&name)
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_cluster_starts_and_gives_separate_databases() {
        let a = super::fresh_database();
        let b = super::fresh_database();
        assert_ne!(a, b);
        assert!(a.starts_with("postgres://d3il@127.0.0.1:"), "{a}");
    }
}
