//! Child processes the cluster benches start (`d3il bench scale`, `d3il bench
//! chaos`): a process killed with SIGKILL when dropped, started and waited
//! for until it prints its ready line, and a process's children.

use anyhow::{bail, Context};
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

/// A child process, killed (SIGKILL) and reaped when dropped.
pub struct Proc(Child);

impl Proc {
    pub fn pid(&self) -> u32 {
        self.0.id()
    }

    /// SIGKILL: no chance to clean up, as a crash or a power cut.
    pub fn kill(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }

    /// True while the process runs (it has not exited).
    pub fn running(&mut self) -> bool {
        matches!(self.0.try_wait(), Ok(None))
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Starts `cmd` with its stdout piped and reads it until a line that starts
/// with `ready`, which it returns; the rest of stdout is drained in the
/// background so that the child never blocks on a full pipe. `what` names
/// the process in the error when it exits first.
pub fn spawn_ready(mut cmd: Command, ready: &str, what: &str) -> anyhow::Result<(Proc, String)> {
    let mut child = cmd
        .stdout(Stdio::piped())
        .spawn()
        .with_context(|| format!("starting {what}"))?;
    let stdout = child.stdout.take().context("stdout is piped")?;
    let proc = Proc(child);
    let mut lines = BufReader::new(stdout).lines();
    let line = loop {
        match lines.next() {
            Some(Ok(l)) if l.starts_with(ready) => break l,
            Some(Ok(_)) => {}
            _ => bail!("{what} exited before it printed `{ready}…`"),
        }
    };
    std::thread::spawn(move || for _ in lines {});
    Ok((proc, line))
}

pub use d3il_pgtemp::children;
