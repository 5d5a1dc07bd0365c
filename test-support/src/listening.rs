//! A child process that prints `listening on HOST:PORT` once it accepts
//! connections (the policy servers of clients/python: `python3 -m
//! d3il_client.serve`), killed and reaped when dropped.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

pub struct Listening {
    pub child: Child,
    pub port: u16,
}

impl Listening {
    /// Spawns `cmd` (stdout piped, stderr inherited, no stdin) and waits for
    /// its first line, `listening on HOST:PORT`; panics with `what` if it
    /// cannot start, or with the line if it is not that.
    pub fn spawn(cmd: &mut Command, what: &str) -> Listening {
        let mut child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout is piped"))
            .read_line(&mut line)
            .expect("read the server's first line");
        let port = line
            .trim()
            .rsplit(':')
            .next()
            .and_then(|p| p.parse().ok())
            .unwrap_or_else(|| panic!("the policy server did not start: `{line}`"));
        Listening { child, port }
    }
}

impl Drop for Listening {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
