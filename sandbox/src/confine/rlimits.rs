//! Resource limits (address space, CPU time, open files, file size, no core
//! dumps, no new processes): the first mechanism, process-wide.

use super::{format_bytes, mech, names, SandboxError};
use d3il_protocol::{Limits, SandboxMechanism};

fn set_rlimit(
    resource: libc::__rlimit_resource_t,
    name: &'static str,
    soft: u64,
    hard: u64,
) -> Result<(), SandboxError> {
    let lim = libc::rlimit {
        rlim_cur: soft as libc::rlim_t,
        rlim_max: hard as libc::rlim_t,
    };
    // SAFETY: plain syscall with a valid pointer to a local struct.
    let rc = unsafe { libc::setrlimit(resource, &lim) };
    if rc != 0 {
        return Err(SandboxError::Rlimit {
            name,
            source: std::io::Error::last_os_error(),
        });
    }
    Ok(())
}

/// A limit of 0 in [`Limits`] means "not limited" (an operator's explicit choice,
/// reported in the detail string).
pub(super) fn apply_rlimits(l: &Limits) -> Result<SandboxMechanism, SandboxError> {
    let mut parts = Vec::new();
    if l.memory_bytes > 0 {
        set_rlimit(
            libc::RLIMIT_AS,
            "address-space",
            l.memory_bytes,
            l.memory_bytes,
        )?;
        parts.push(format!("address space {}", format_bytes(l.memory_bytes)));
    } else {
        parts.push("address space unlimited (memory_bytes = 0)".into());
    }
    if l.cpu_seconds > 0 {
        // Soft limit sends SIGXCPU (reported as CpuLimit); the hard limit a few
        // seconds later is the kernel's SIGKILL backstop.
        set_rlimit(
            libc::RLIMIT_CPU,
            "CPU-time",
            l.cpu_seconds,
            l.cpu_seconds.saturating_add(2),
        )?;
        parts.push(format!("CPU {} s", l.cpu_seconds));
    } else {
        parts.push("CPU unlimited (cpu_seconds = 0)".into());
    }
    if l.open_files > 0 {
        set_rlimit(
            libc::RLIMIT_NOFILE,
            "open-files",
            l.open_files,
            l.open_files,
        )?;
        parts.push(format!("open files {}", l.open_files));
    } else {
        parts.push("open files unlimited (open_files = 0)".into());
    }
    // A file-size limit of 0 would be a real limit (no writes), not "unlimited":
    // the worker writes nothing anyway, so 0 is honoured literally.
    set_rlimit(
        libc::RLIMIT_FSIZE,
        "file-size",
        l.file_size_bytes,
        l.file_size_bytes,
    )?;
    parts.push(format!("file size {}", format_bytes(l.file_size_bytes)));
    // No core dumps: they would be files left behind and could leak memory contents.
    set_rlimit(libc::RLIMIT_CORE, "core-size", 0, 0)?;
    parts.push("core dumps off".into());
    Ok(mech(names::RLIMITS, true, parts.join(", ")))
}
