//! Slurm for real (docs/cluster.md): starts a single-node Slurm cluster from
//! Debian's `slurm-wlm` and `munge` (installed by `./dev test`) in a temporary
//! directory — munged with its own key and socket, slurmctld and slurmd on
//! 127.0.0.1 on free ports — submits the documented array and merge jobs
//! with `docs/cluster/d3il-slurm-submit.sh` for a quick-protocol evaluation,
//! waits for them and compares the merged result with a plain `d3il eval`.

use crate::shard_support;

use d3il_test_support::free_port;
use shard_support::{assert_same_result, table};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const POLICY: &str = "scripted:pushing:all-modes";

/// The cluster's daemons; killed (by their own pids) when dropped.
struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
    daemons: Vec<(&'static str, Child)>,
}

impl Drop for Cluster {
    fn drop(&mut self) {
        // slurmd first, so that it does not report a lost controller.
        for (_, child) in self.daemons.iter_mut().rev() {
            let _ = child.kill();
            let _ = child.wait();
        }
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

fn program(name: &str) -> PathBuf {
    for dir in ["/usr/sbin", "/usr/bin", "/sbin", "/bin"] {
        let p = Path::new(dir).join(name);
        if p.is_file() {
            return p;
        }
    }
    panic!("{name} is not installed: `./dev test` installs Debian's slurm-wlm and munge");
}

fn run(cmd: &mut Command, what: &str) -> String {
    let out = cmd.output().unwrap_or_else(|e| panic!("{what}: {e}"));
    d3il_test_support::succeeded(&out, what)
}

impl Cluster {
    fn logs(&self) -> String {
        let mut s = String::new();
        for f in ["munged.log", "slurmctld.log", "slurmd.log"] {
            let text = std::fs::read_to_string(self.dir.join(f)).unwrap_or_default();
            let tail: Vec<&str> = text.lines().rev().take(30).collect();
            s += &format!("--- {f} (last lines)\n");
            for l in tail.iter().rev() {
                s += l;
                s.push('\n');
            }
        }
        s
    }

    fn cmd(&self, name: &str) -> Command {
        let mut c = Command::new(program(name));
        c.env("SLURM_CONF", &self.conf);
        c
    }

    fn spawn(&mut self, name: &'static str, args: &[&str]) {
        let log = std::fs::File::create(self.dir.join(format!("{name}.stderr"))).unwrap();
        let child = self
            .cmd(name)
            .args(args)
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("starting {name}: {e}"));
        self.daemons.push((name, child));
    }

    fn start() -> Cluster {
        let dir = std::env::temp_dir().join(format!("d3il-slurm-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        // munged wants its key private and its socket's directory searchable by all.
        let key_dir = dir.join("munge");
        let run_dir = dir.join("run");
        for d in [&key_dir, &run_dir, &dir.join("state"), &dir.join("spool")] {
            std::fs::create_dir_all(d).unwrap();
        }
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
        std::fs::set_permissions(&run_dir, std::fs::Permissions::from_mode(0o755)).unwrap();
        std::fs::set_permissions(&key_dir, std::fs::Permissions::from_mode(0o700)).unwrap();
        let key = key_dir.join("munge.key");
        let socket = run_dir.join("munge.sock");
        let conf = dir.join("slurm.conf");
        let mut cluster = Cluster {
            dir: dir.clone(),
            conf: conf.clone(),
            daemons: Vec::new(),
        };
        run(
            Command::new(program("mungekey"))
                .arg("--create")
                .arg("--keyfile")
                .arg(&key),
            "mungekey",
        );
        let p = |path: &Path| path.to_string_lossy().into_owned();
        cluster.spawn(
            "munged",
            &[
                "--foreground",
                &format!("--key-file={}", p(&key)),
                &format!("--socket={}", p(&socket)),
                &format!("--pid-file={}", p(&run_dir.join("munged.pid"))),
                &format!("--log-file={}", p(&dir.join("munged.log"))),
                &format!("--seed-file={}", p(&key_dir.join("munged.seed"))),
            ],
        );
        wait_for(&cluster, "munged's socket", Duration::from_secs(30), || {
            socket.exists()
        });

        // slurmctld must run on a host named in SlurmctldHost: this one.
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap();
        let host = host.trim().split('.').next().unwrap().to_string();
        let user = run(Command::new("id").arg("-un"), "id -un")
            .trim()
            .to_string();
        let d = p(&dir);
        let text = format!(
            "# Generated by tests/shard/slurm_array.rs: a one-node cluster on 127.0.0.1.
ClusterName=d3iltest
SlurmctldHost={host}(127.0.0.1)
SlurmctldPort={ctld_port}
SlurmdPort={slurmd_port}
SlurmUser={user}
SlurmdUser={user}
AuthType=auth/munge
AuthInfo=socket={socket}
CredType=cred/munge
StateSaveLocation={d}/state
SlurmdSpoolDir={d}/spool
SlurmctldPidFile={d}/run/slurmctld.pid
SlurmdPidFile={d}/run/slurmd.pid
SlurmctldLogFile={d}/slurmctld.log
SlurmdLogFile={d}/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
# The node has the CPUs said here whatever the machine has.
SlurmdParameters=config_overrides
MpiDefault=none
ReturnToService=2
InactiveLimit=0
KillWait=5
NodeName=d3il-node NodeHostname=localhost NodeAddr=127.0.0.1 CPUs=2 State=UNKNOWN
PartitionName=debug Nodes=d3il-node Default=YES MaxTime=INFINITE State=UP
",
            ctld_port = free_port(),
            slurmd_port = free_port(),
            socket = p(&socket),
        );
        std::fs::write(&conf, text).unwrap();
        cluster.spawn("slurmctld", &["-D", "-i"]);
        cluster.spawn("slurmd", &["-D", "-N", "d3il-node"]);
        wait_for(
            &cluster,
            "the node to be idle",
            Duration::from_secs(60),
            || {
                cluster
                    .cmd("sinfo")
                    .args(["-h", "-o", "%T"])
                    .output()
                    .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "idle")
            },
        );
        cluster
    }
}

fn wait_for(cluster: &Cluster, what: &str, limit: Duration, mut ready: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !ready() {
        if t0.elapsed() > limit {
            panic!(
                "timed out after {limit:?} waiting for {what}\n{}",
                cluster.logs()
            );
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn documented_sbatch_array_merges_to_the_plain_evaluation() {
    let cluster = Cluster::start();
    let work = cluster.dir.join("work");
    std::fs::create_dir_all(&work).unwrap();
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let assets = repo.join("assets");
    let d3il = env!("CARGO_BIN_EXE_d3il");

    // The documented submission: an array of 3 shards and the merge job.
    let ids = run(
        cluster
            .cmd("bash")
            .arg(repo.join("docs/cluster/d3il-slurm-submit.sh"))
            .args(["pushing", POLICY, "3", "merged.json"])
            .current_dir(&work)
            .env("D3IL", d3il)
            .env("D3IL_ASSETS", &assets)
            .env("D3IL_PROTOCOL", "quick")
            .env("D3IL_SEED", "7"),
        "d3il-slurm-submit.sh",
    );
    let ids: Vec<&str> = ids.split_whitespace().collect();
    assert_eq!(ids.len(), 2, "{ids:?}");
    let (array, merge) = (ids[0], ids[1]);
    let jobs = format!("{array},{merge}");
    // Both jobs leave the queue once done (or failed).
    wait_for(&cluster, "the jobs", Duration::from_secs(600), || {
        cluster
            .cmd("squeue")
            .args(["-h", "-j", &jobs])
            .output()
            .is_ok_and(|o| o.status.success() && o.stdout.iter().all(u8::is_ascii_whitespace))
    });
    let job_outputs = || {
        let mut s = String::new();
        for e in std::fs::read_dir(&work).unwrap().flatten() {
            if e.path().extension().is_some_and(|x| x == "out") {
                s += &format!("--- {}\n", e.path().display());
                s += &std::fs::read_to_string(e.path()).unwrap_or_default();
            }
        }
        s
    };
    for k in 1..=3 {
        let part = work.join(format!("parts/part-{k}-of-3.json"));
        assert!(
            part.is_file(),
            "shard {k} wrote no part\n{}\n{}",
            job_outputs(),
            cluster.logs()
        );
        let out = work.join(format!("d3il-eval-{array}_{k}.out"));
        let text = std::fs::read_to_string(&out).unwrap_or_default();
        assert!(text.contains(&format!("shard {k}/3")), "{text}");
    }
    let merged = work.join("merged.json");
    assert!(
        merged.is_file(),
        "the merge job wrote no result\n{}\n{}",
        job_outputs(),
        cluster.logs()
    );

    // The same evaluation without Slurm.
    let plain = run(
        Command::new(d3il)
            .args(["eval", "--task", "pushing", "--policy", POLICY])
            .args(["--protocol", "quick", "--seed", "7", "--json", "plain.json"])
            .current_dir(&work)
            .env("D3IL_ASSETS", &assets),
        "plain d3il eval",
    );
    assert_same_result(&work.join("plain.json"), &merged);
    // The merge job printed the table `d3il eval` prints.
    let merge_out = std::fs::read_to_string(work.join(format!("d3il-merge-{merge}.out"))).unwrap();
    for line in table(&plain) {
        assert!(merge_out.contains(line), "{line:?} missing in\n{merge_out}");
    }
    drop(cluster);
}
