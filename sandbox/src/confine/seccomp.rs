//! Seccomp, installed last: a deny list of system calls (EPERM) and the
//! clone3 answer (ENOSYS).

use super::{mech, names, SandboxError};
use d3il_protocol::SandboxMechanism;
use seccompiler::{
    BpfProgram, SeccompAction, SeccompCmpArgLen, SeccompCmpOp, SeccompCondition, SeccompFilter,
    SeccompRule,
};
use std::collections::BTreeMap;

/// System calls denied outright (EPERM). Process creation, debugging other
/// processes, kernel/module/mount/namespace administration, and kernel attack
/// surface a policy evaluation never needs (bpf, io_uring, userfaultfd, perf).
pub(super) const DENIED: &[(libc::c_long, &str)] = &[
    (libc::SYS_fork, "fork"),
    (libc::SYS_vfork, "vfork"),
    (libc::SYS_execve, "execve"),
    (libc::SYS_execveat, "execveat"),
    (libc::SYS_ptrace, "ptrace"),
    (libc::SYS_process_vm_readv, "process_vm_readv"),
    (libc::SYS_process_vm_writev, "process_vm_writev"),
    (libc::SYS_kcmp, "kcmp"),
    (libc::SYS_pidfd_open, "pidfd_open"),
    (libc::SYS_pidfd_getfd, "pidfd_getfd"),
    (libc::SYS_pidfd_send_signal, "pidfd_send_signal"),
    (libc::SYS_tkill, "tkill"),
    (libc::SYS_setsid, "setsid"),
    (libc::SYS_setpgid, "setpgid"),
    (libc::SYS_setuid, "setuid"),
    (libc::SYS_setgid, "setgid"),
    (libc::SYS_setreuid, "setreuid"),
    (libc::SYS_setregid, "setregid"),
    (libc::SYS_setresuid, "setresuid"),
    (libc::SYS_setresgid, "setresgid"),
    (libc::SYS_setgroups, "setgroups"),
    (libc::SYS_unshare, "unshare"),
    (libc::SYS_setns, "setns"),
    (libc::SYS_mount, "mount"),
    (libc::SYS_umount2, "umount2"),
    (libc::SYS_pivot_root, "pivot_root"),
    (libc::SYS_chroot, "chroot"),
    (libc::SYS_move_mount, "move_mount"),
    (libc::SYS_open_tree, "open_tree"),
    (libc::SYS_fsopen, "fsopen"),
    (libc::SYS_fsconfig, "fsconfig"),
    (libc::SYS_fsmount, "fsmount"),
    (libc::SYS_fspick, "fspick"),
    (libc::SYS_mount_setattr, "mount_setattr"),
    (libc::SYS_swapon, "swapon"),
    (libc::SYS_swapoff, "swapoff"),
    (libc::SYS_reboot, "reboot"),
    (libc::SYS_kexec_load, "kexec_load"),
    (libc::SYS_kexec_file_load, "kexec_file_load"),
    (libc::SYS_init_module, "init_module"),
    (libc::SYS_finit_module, "finit_module"),
    (libc::SYS_delete_module, "delete_module"),
    (libc::SYS_acct, "acct"),
    (libc::SYS_quotactl, "quotactl"),
    (libc::SYS_syslog, "syslog"),
    (libc::SYS_vhangup, "vhangup"),
    (libc::SYS_settimeofday, "settimeofday"),
    (libc::SYS_clock_settime, "clock_settime"),
    (libc::SYS_clock_adjtime, "clock_adjtime"),
    (libc::SYS_adjtimex, "adjtimex"),
    (libc::SYS_mknod, "mknod"),
    (libc::SYS_mknodat, "mknodat"),
    (libc::SYS_open_by_handle_at, "open_by_handle_at"),
    (libc::SYS_name_to_handle_at, "name_to_handle_at"),
    (libc::SYS_bpf, "bpf"),
    (libc::SYS_perf_event_open, "perf_event_open"),
    (libc::SYS_userfaultfd, "userfaultfd"),
    (libc::SYS_io_uring_setup, "io_uring_setup"),
    (libc::SYS_io_uring_enter, "io_uring_enter"),
    (libc::SYS_io_uring_register, "io_uring_register"),
    (libc::SYS_keyctl, "keyctl"),
    (libc::SYS_add_key, "add_key"),
    (libc::SYS_request_key, "request_key"),
    (libc::SYS_fanotify_init, "fanotify_init"),
    (libc::SYS_personality, "personality"),
    (libc::SYS_uselib, "uselib"),
    (libc::SYS_iopl, "iopl"),
    (libc::SYS_ioperm, "ioperm"),
];

fn cond(
    arg: u8,
    len: SeccompCmpArgLen,
    op: SeccompCmpOp,
    v: u64,
) -> Result<SeccompCondition, SandboxError> {
    SeccompCondition::new(arg, len, op, v).map_err(|e| SandboxError::Seccomp(e.to_string()))
}

fn rule(c: Vec<SeccompCondition>) -> Result<SeccompRule, SandboxError> {
    SeccompRule::new(c).map_err(|e| SandboxError::Seccomp(e.to_string()))
}

fn arch() -> Result<seccompiler::TargetArch, SandboxError> {
    std::env::consts::ARCH
        .try_into()
        .map_err(|e: seccompiler::BackendError| {
            SandboxError::Seccomp(format!("{e} ({})", std::env::consts::ARCH))
        })
}

/// The deny-list filter (EPERM). A deny list rather than an allow list: tract,
/// rayon, glibc and MuJoCo use a wide and version-dependent set of ordinary
/// syscalls (mmap, futex, madvise, sched_*, ...), and an allow list that misses
/// one turns into random crashes. The dangerous ones are all listed here.
pub(crate) fn deny_filter(network_allowed: bool) -> Result<BpfProgram, SandboxError> {
    use SeccompCmpArgLen::{Dword, Qword};
    let mut rules: BTreeMap<i64, Vec<SeccompRule>> = BTreeMap::new();
    for &(nr, _) in DENIED {
        rules.insert(nr, vec![]);
    }
    // Threads are clone(CLONE_THREAD|...); anything else creates a process.
    rules.insert(
        libc::SYS_clone,
        vec![rule(vec![cond(
            0,
            Qword,
            SeccompCmpOp::MaskedEq(libc::CLONE_THREAD as u64),
            0,
        )?])?],
    );
    // Signals only to ourselves (abort() -> tgkill(self), raise, ...).
    // SAFETY: getpid has no preconditions.
    let me = unsafe { libc::getpid() } as u32 as u64;
    for nr in [
        libc::SYS_kill,
        libc::SYS_tgkill,
        libc::SYS_rt_sigqueueinfo,
        libc::SYS_rt_tgsigqueueinfo,
    ] {
        rules.insert(nr, vec![rule(vec![cond(0, Dword, SeccompCmpOp::Ne, me)?])?]);
    }
    if !network_allowed {
        // File policies: no sockets except unix ones (already scoped by landlock
        // and useless in an empty network namespace).
        rules.insert(
            libc::SYS_socket,
            vec![rule(vec![cond(
                0,
                Dword,
                SeccompCmpOp::Ne,
                libc::AF_UNIX as u64,
            )?])?],
        );
    }
    let filter = SeccompFilter::new(
        rules,
        SeccompAction::Allow,
        SeccompAction::Errno(libc::EPERM as u32),
        arch()?,
    )
    .map_err(|e| SandboxError::Seccomp(e.to_string()))?;
    filter
        .try_into()
        .map_err(|e: seccompiler::BackendError| SandboxError::Seccomp(e.to_string()))
}

/// clone3 passes its flags in a struct the filter cannot inspect, so it answers
/// ENOSYS: glibc then falls back to clone(2), which the deny filter checks.
pub(super) fn clone3_filter() -> Result<BpfProgram, SandboxError> {
    let mut rules: BTreeMap<i64, Vec<SeccompRule>> = BTreeMap::new();
    rules.insert(libc::SYS_clone3, vec![]);
    let filter = SeccompFilter::new(
        rules,
        SeccompAction::Allow,
        SeccompAction::Errno(libc::ENOSYS as u32),
        arch()?,
    )
    .map_err(|e| SandboxError::Seccomp(e.to_string()))?;
    filter
        .try_into()
        .map_err(|e: seccompiler::BackendError| SandboxError::Seccomp(e.to_string()))
}

pub(super) fn apply_seccomp(network_allowed: bool) -> Result<SandboxMechanism, SandboxError> {
    // SAFETY: prctl(PR_SET_NO_NEW_PRIVS) has no memory arguments. Landlock set it
    // already when available; set it again in case landlock was missing.
    if unsafe { libc::prctl(libc::PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) } != 0 {
        return Err(SandboxError::Seccomp(format!(
            "PR_SET_NO_NEW_PRIVS: {}",
            std::io::Error::last_os_error()
        )));
    }
    // SAFETY: reading the current seccomp mode has no side effects.
    let mode = unsafe { libc::prctl(libc::PR_GET_SECCOMP, 0, 0, 0, 0) };
    if mode < 0 {
        let e = std::io::Error::last_os_error();
        return Ok(mech(
            names::SECCOMP,
            false,
            format!("kernel has no seccomp ({e}); enable CONFIG_SECCOMP_FILTER"),
        ));
    }
    let deny = deny_filter(network_allowed)?;
    let clone3 = clone3_filter()?;
    seccompiler::apply_filter_all_threads(&clone3)
        .map_err(|e| SandboxError::Seccomp(e.to_string()))?;
    seccompiler::apply_filter_all_threads(&deny)
        .map_err(|e| SandboxError::Seccomp(e.to_string()))?;
    let mut detail = format!(
        "denied (EPERM): process creation (fork, vfork, clone without CLONE_THREAD, execve, execveat), \
         ptrace and cross-process memory access, signals to other processes, session/group/uid changes, \
         namespaces, mounts, modules, bpf, io_uring, perf, userfaultfd, keyrings ({} system calls denied \
         outright, 5 by argument); clone3 -> ENOSYS",
        DENIED.len()
    );
    if !network_allowed {
        detail.push_str("; no sockets except AF_UNIX");
    }
    Ok(mech(names::SECCOMP, true, detail))
}
