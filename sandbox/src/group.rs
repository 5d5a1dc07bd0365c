//! The worker's process group: killing, waiting for and reaping it
//! (split from `parent`, which runs the worker).

use std::time::{Duration, Instant};

pub(crate) struct ReapGuard {
    pub(crate) pid: libc::pid_t,
    pub(crate) armed: bool,
}

impl Drop for ReapGuard {
    fn drop(&mut self) {
        if self.armed {
            kill_group(self.pid);
            reap(self.pid);
        }
    }
}

/// Polls until no live process is left in group `pgid`, or `limit` passes.
pub(crate) fn wait_group_gone(pgid: libc::pid_t, limit: Duration) {
    let until = Instant::now() + limit;
    while !live_group_members(pgid).is_empty() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Pids of the live (not zombie) processes whose process group is `pgid`, read
/// from `/proc` (empty if `/proc` cannot be read).
pub fn live_group_members(pgid: libc::pid_t) -> Vec<libc::pid_t> {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    dir.flatten()
        .filter_map(|e| e.file_name().to_string_lossy().parse::<libc::pid_t>().ok())
        .filter(|pid| {
            let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
                return false;
            };
            // "pid (comm) state ppid pgrp ...": comm may contain spaces and ')'.
            let Some(rest) = stat.rfind(')').map(|i| &stat[i + 1..]) else {
                return false;
            };
            let f: Vec<&str> = rest.split_whitespace().collect();
            f.len() > 2 && f[0] != "Z" && f[2].parse::<libc::pid_t>() == Ok(pgid)
        })
        .collect()
}

pub(crate) fn kill_group(pid: libc::pid_t) {
    // SAFETY: kill has no memory arguments; -pid names the worker's group.
    unsafe {
        libc::kill(-pid, libc::SIGKILL);
    }
}

/// Whether the worker has exited, without reaping it (its pid keeps naming the
/// process group until we reap it).
pub(crate) fn has_exited(pid: libc::pid_t) -> bool {
    // SAFETY: zeroed siginfo is a valid out-parameter for waitid.
    let mut info: libc::siginfo_t = unsafe { std::mem::zeroed() };
    // SAFETY: valid pointer to a local.
    let rc = unsafe {
        libc::waitid(
            libc::P_PID,
            pid as libc::id_t,
            &mut info,
            libc::WEXITED | libc::WNOWAIT | libc::WNOHANG,
        )
    };
    // SAFETY: si_pid is valid to read after waitid.
    rc != 0 || unsafe { info.si_pid() } != 0
}

/// Wait (without reaping) until the worker has exited or the deadline passed.
pub(crate) fn wait_exited(pid: libc::pid_t, deadline: Instant) -> bool {
    loop {
        if has_exited(pid) {
            return true;
        }
        if Instant::now() >= deadline {
            return false;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// How the worker ended.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Status {
    Exited(i32),
    Signaled(i32),
    Unknown,
}

pub(crate) fn reap(pid: libc::pid_t) -> (Status, Duration) {
    let mut status: libc::c_int = 0;
    // SAFETY: zeroed rusage is a valid out-parameter.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let rc = loop {
        // SAFETY: valid pointers to locals.
        let rc = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
        if rc == -1 && std::io::Error::last_os_error().raw_os_error() == Some(libc::EINTR) {
            continue;
        }
        break rc;
    };
    if rc != pid {
        return (Status::Unknown, Duration::ZERO);
    }
    let tv = |t: libc::timeval| Duration::new(t.tv_sec as u64, (t.tv_usec as u32) * 1000);
    let cpu = tv(usage.ru_utime) + tv(usage.ru_stime);
    let s = if libc::WIFEXITED(status) {
        Status::Exited(libc::WEXITSTATUS(status))
    } else if libc::WIFSIGNALED(status) {
        Status::Signaled(libc::WTERMSIG(status))
    } else {
        Status::Unknown
    };
    (s, cpu)
}
