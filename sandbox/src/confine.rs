//! Child-side confinement: the worker calls [`confine`] on itself, while it is
//! still single-threaded and before it parses anything from the submission.
//!
//! Order matters:
//! 1. rlimits (process-wide, nothing else needs them lifted);
//! 2. a new network namespace for file policies (needs CAP_SYS_ADMIN or a user
//!    namespace, so it must come before capabilities are dropped);
//! 3. capabilities dropped when running as root;
//! 4. landlock (filesystem read-only allow-list, TCP connect/bind rules, signal and
//!    abstract-socket scoping);
//! 5. seccomp last, because it forbids `unshare` and friends used above.
//!
//! Each step reports a [`SandboxMechanism`]; a mechanism the kernel lacks is
//! reported inactive with the reason, never silently skipped (issue 6).

use d3il_protocol::{Job, Limits, PolicySource, SandboxMechanism};
use landlock::{
    path_beneath_rules, Access, AccessFs, AccessNet, NetPort, Ruleset, RulesetAttr,
    RulesetCreatedAttr, RulesetStatus, Scope, ABI,
};
use seccompiler::{
    BpfProgram, SeccompAction, SeccompCmpArgLen, SeccompCmpOp, SeccompCondition, SeccompFilter,
    SeccompRule,
};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Mechanism names as they appear in [`SandboxMechanism::name`] (stable: the
/// server's admin page and `--require` use them).
pub mod names {
    pub const RLIMITS: &str = "rlimits";
    pub const NETWORK_NAMESPACE: &str = "network-namespace";
    pub const CAPABILITIES: &str = "capabilities";
    pub const LANDLOCK_FS: &str = "landlock-fs";
    pub const LANDLOCK_NET: &str = "landlock-net";
    pub const LANDLOCK_SCOPE: &str = "landlock-scope";
    pub const SECCOMP: &str = "seccomp";
    pub const ALL: [&str; 7] = [
        RLIMITS,
        NETWORK_NAMESPACE,
        CAPABILITIES,
        LANDLOCK_FS,
        LANDLOCK_NET,
        LANDLOCK_SCOPE,
        SECCOMP,
    ];
}

/// Extra directories the worker may read, colon-separated (e.g. GPU driver files
/// for headless rendering). A knob for operators; documented in docs/sandbox.md.
pub const EXTRA_READ_ENV: &str = "D3IL_SANDBOX_EXTRA_READ";

#[derive(Debug, thiserror::Error)]
pub enum SandboxError {
    #[error(
        "the sandbox must be set up while the worker is single-threaded, but it has {0} threads; \
         call confine() before starting any thread"
    )]
    Multithreaded(usize),
    #[error("could not set the {name} resource limit: {source}")]
    Rlimit {
        name: &'static str,
        source: std::io::Error,
    },
    #[error("could not enter a new network namespace: {0}")]
    Network(String),
    #[error("could not drop capabilities: {0}")]
    Capabilities(std::io::Error),
    #[error("could not apply the landlock rules: {0}")]
    Landlock(String),
    #[error("could not install the seccomp filter: {0}")]
    Seccomp(String),
    #[error(
        "the policy file {path} cannot be opened: {source}; check that it exists and is readable"
    )]
    PolicyFile {
        path: PathBuf,
        source: std::io::Error,
    },
}

fn mech(name: &str, active: bool, detail: impl Into<String>) -> SandboxMechanism {
    SandboxMechanism {
        name: name.to_string(),
        active,
        detail: detail.into(),
    }
}

/// Confine the calling process for `job`. `policy_file` is the one file besides
/// the assets that the worker may read (the ONNX file); pass None for remote or
/// scripted policies.
///
/// Returns the mechanisms with whether each is in force. Errors only when a
/// mechanism that the kernel supports failed to apply (then the worker must not
/// go on, exit code `SANDBOX_FAILED`).
pub fn confine(
    job: &Job,
    policy_file: Option<&Path>,
) -> Result<Vec<SandboxMechanism>, SandboxError> {
    // Landlock and seccomp apply to the calling thread (and threads it creates
    // later); unshare(CLONE_NEWNET) too. A thread started earlier would escape.
    let threads = thread_count();
    if threads > 1 {
        return Err(SandboxError::Multithreaded(threads));
    }
    if let Some(p) = policy_file {
        // Fail with a clear message now rather than with EACCES later.
        std::fs::File::open(p).map_err(|source| SandboxError::PolicyFile {
            path: p.to_path_buf(),
            source,
        })?;
    }
    let network_allowed = matches!(job.policy, PolicySource::Remote { .. });
    let mut out = Vec::new();
    out.push(apply_rlimits(&job.limits)?);
    out.push(if network_allowed {
        mech(
            names::NETWORK_NAMESPACE,
            false,
            "not used: a remote policy needs the network; TCP is limited to the endpoint's port \
             by landlock-net and the endpoint address is checked",
        )
    } else {
        enter_network_namespace()?
    });
    out.push(drop_capabilities()?);
    let connect_port = match &job.policy {
        PolicySource::Remote { url } => endpoint_port(url),
        _ => None,
    };
    let rendering = job.manifest.obs_type == d3il_protocol::ObsType::Image;
    out.extend(apply_landlock(
        Path::new(&job.assets_dir),
        policy_file,
        network_allowed,
        connect_port,
        rendering,
    )?);
    out.push(apply_seccomp(network_allowed)?);
    Ok(out)
}

fn thread_count() -> usize {
    std::fs::read_dir("/proc/self/task")
        .map(|d| d.count())
        .unwrap_or(1)
}

/// The TCP port of a ws/wss URL, if it parses (validation proper happens later in
/// `validate_endpoint`; a bad URL just gets no port allowed).
fn endpoint_port(url: &str) -> Option<u16> {
    url::Url::parse(url).ok()?.port_or_known_default()
}

pub(crate) fn format_bytes(b: u64) -> String {
    const GIB: u64 = 1 << 30;
    const MIB: u64 = 1 << 20;
    const KIB: u64 = 1 << 10;
    if b >= GIB && b.is_multiple_of(GIB / 4) {
        format!("{} GiB", fmt_frac(b as f64 / GIB as f64))
    } else if b >= MIB {
        format!("{} MiB", fmt_frac(b as f64 / MIB as f64))
    } else if b >= KIB {
        format!("{} KiB", fmt_frac(b as f64 / KIB as f64))
    } else {
        format!("{b} bytes")
    }
}

fn fmt_frac(x: f64) -> String {
    if (x - x.round()).abs() < 1e-9 {
        format!("{}", x.round() as u64)
    } else {
        format!("{x:.2}")
    }
}

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
fn apply_rlimits(l: &Limits) -> Result<SandboxMechanism, SandboxError> {
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

/// A new, empty network namespace: only a loopback interface that is down, so
/// every connect (including to 127.0.0.1 on the host) fails with ENETUNREACH.
fn enter_network_namespace() -> Result<SandboxMechanism, SandboxError> {
    // SAFETY: unshare only affects this (single-threaded) process.
    if unsafe { libc::unshare(libc::CLONE_NEWNET) } == 0 {
        return Ok(mech(
            names::NETWORK_NAMESPACE,
            true,
            "new network namespace with no usable interface (loopback down)",
        ));
    }
    let first = std::io::Error::last_os_error();
    if first.raw_os_error() == Some(libc::EPERM) {
        // Not root: an unprivileged user namespace grants CAP_SYS_ADMIN over a new
        // network namespace.
        // SAFETY: as above.
        if unsafe { libc::unshare(libc::CLONE_NEWUSER | libc::CLONE_NEWNET) } == 0 {
            return Ok(mech(
                names::NETWORK_NAMESPACE,
                true,
                "new user + network namespace with no usable interface (loopback down)",
            ));
        }
        let second = std::io::Error::last_os_error();
        return Ok(mech(
            names::NETWORK_NAMESPACE,
            false,
            format!(
                "kernel refused a network namespace ({first}) and a user namespace ({second}); \
                 run the worker as root or enable unprivileged user namespaces"
            ),
        ));
    }
    if first.raw_os_error() == Some(libc::EINVAL) || first.raw_os_error() == Some(libc::ENOSYS) {
        return Ok(mech(
            names::NETWORK_NAMESPACE,
            false,
            format!("kernel has no network namespaces ({first})"),
        ));
    }
    Err(SandboxError::Network(first.to_string()))
}

/// Root keeps uid 0 (file ownership checks) but loses every capability, so no
/// mount, raw socket, module loading, DAC override ...
fn drop_capabilities() -> Result<SandboxMechanism, SandboxError> {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        return Ok(mech(
            names::CAPABILITIES,
            true,
            "not root: no capabilities to drop",
        ));
    }
    #[repr(C)]
    struct CapHeader {
        version: u32,
        pid: i32,
    }
    #[repr(C)]
    #[derive(Clone, Copy)]
    struct CapData {
        effective: u32,
        permitted: u32,
        inheritable: u32,
    }
    const LINUX_CAPABILITY_VERSION_3: u32 = 0x2008_0522;
    let mut header = CapHeader {
        version: LINUX_CAPABILITY_VERSION_3,
        pid: 0,
    };
    let data = [CapData {
        effective: 0,
        permitted: 0,
        inheritable: 0,
    }; 2];
    // SAFETY: capset with a v3 header and two data structs, as capset(2) requires.
    let rc = unsafe {
        libc::syscall(
            libc::SYS_capset,
            &mut header as *mut CapHeader,
            data.as_ptr(),
        )
    };
    if rc != 0 {
        return Err(SandboxError::Capabilities(std::io::Error::last_os_error()));
    }
    Ok(mech(
        names::CAPABILITIES,
        true,
        "running as root: all capabilities dropped (effective, permitted, inheritable)",
    ))
}

/// The kernel's landlock ABI version, or the errno explaining why there is none.
pub fn landlock_abi() -> Result<i32, std::io::Error> {
    const LANDLOCK_CREATE_RULESET_VERSION: libc::c_uint = 1;
    // SAFETY: the documented way to query the ABI: null attr, size 0, version flag.
    let v = unsafe {
        libc::syscall(
            libc::SYS_landlock_create_ruleset,
            std::ptr::null::<u8>(),
            0usize,
            LANDLOCK_CREATE_RULESET_VERSION,
        )
    };
    if v < 0 {
        Err(std::io::Error::last_os_error())
    } else {
        Ok(v as i32)
    }
}

/// Read-only system paths the worker needs: the dynamic loader's cache and the
/// library directories (most libraries are mapped before confinement, but dlopen
/// happens later, e.g. libnss for DNS or libgcc_s for unwinding), and the few
/// /proc and /sys files the Rust runtime reads to size thread pools.
const SYSTEM_READ: &[&str] = &[
    "/usr/lib",
    "/usr/lib64",
    "/usr/local/lib",
    "/lib",
    "/lib64",
    "/etc/ld.so.cache",
    "/etc/ld.so.conf",
    "/etc/ld.so.conf.d",
    "/etc/localtime",
    "/sys/fs/cgroup",
    "/sys/devices/system/cpu",
    "/dev/null",
    "/dev/zero",
    "/dev/urandom",
];

/// Headless rendering for image jobs (libglvnd's EGL vendor list and Mesa's
/// driver configuration; the driver libraries are under /usr/lib). No /dev/dri:
/// image jobs render in software, which gives the same pixels on every host.
const RENDER_READ: &[&str] = &["/usr/share/glvnd", "/usr/share/drirc.d", "/etc/drirc"];

/// Name resolution for remote endpoints.
const RESOLVER_READ: &[&str] = &[
    "/etc/resolv.conf",
    "/etc/hosts",
    "/etc/nsswitch.conf",
    "/etc/host.conf",
    "/etc/gai.conf",
    "/etc/services",
];

fn apply_landlock(
    assets: &Path,
    policy_file: Option<&Path>,
    network_allowed: bool,
    connect_port: Option<u16>,
    rendering: bool,
) -> Result<Vec<SandboxMechanism>, SandboxError> {
    let abi = match landlock_abi() {
        Ok(v) => v,
        Err(e) => {
            let why = format!(
                "kernel has no landlock ({e}); enable CONFIG_SECURITY_LANDLOCK and lsm=landlock"
            );
            return Ok(vec![
                mech(names::LANDLOCK_FS, false, why.clone()),
                mech(names::LANDLOCK_NET, false, why.clone()),
                mech(names::LANDLOCK_SCOPE, false, why),
            ]);
        }
    };
    // Request everything up to V6 (net from V4, scopes from V6); the crate drops
    // what the running kernel lacks (best effort) and we report it below.
    let want = ABI::V6;
    let ll = |e: landlock::RulesetError| SandboxError::Landlock(e.to_string());
    let read = AccessFs::from_read(want);
    let mut ruleset = Ruleset::default()
        .handle_access(AccessFs::from_all(want))
        .map_err(ll)?
        .handle_access(AccessNet::from_all(want))
        .map_err(ll)?
        .scope(Scope::from_all(want))
        .map_err(ll)?
        .create()
        .map_err(ll)?;
    let mut readable: Vec<PathBuf> = vec![assets.to_path_buf()];
    readable.extend(SYSTEM_READ.iter().map(PathBuf::from));
    // /proc/self is a symlink; resolve it so the rule covers this process only.
    readable.push(PathBuf::from(format!("/proc/{}", std::process::id())));
    if let Some(p) = policy_file {
        readable.push(p.to_path_buf());
    }
    if network_allowed {
        readable.extend(RESOLVER_READ.iter().map(PathBuf::from));
    }
    if rendering {
        readable.extend(RENDER_READ.iter().map(PathBuf::from));
    }
    if let Ok(extra) = std::env::var(EXTRA_READ_ENV) {
        readable.extend(
            extra
                .split(':')
                .filter(|s| !s.is_empty())
                .map(PathBuf::from),
        );
    }
    ruleset = ruleset
        .add_rules(path_beneath_rules(&readable, read))
        .map_err(ll)?;
    let mut ports = Vec::new();
    if let Some(port) = connect_port {
        ports.push(port);
        // DNS over TCP (truncated answers) while resolving the endpoint's host.
        ports.push(53);
    }
    for &p in &ports {
        ruleset = ruleset
            .add_rule(NetPort::new(p, AccessNet::ConnectTcp))
            .map_err(ll)?;
    }
    let status = ruleset.restrict_self().map_err(ll)?;
    let enforced = !matches!(status.ruleset, RulesetStatus::NotEnforced);
    let how = match status.ruleset {
        RulesetStatus::FullyEnforced => "fully enforced",
        RulesetStatus::PartiallyEnforced => "partially enforced",
        RulesetStatus::NotEnforced => "not enforced",
    };
    let fs_detail = format!(
        "landlock ABI v{abi} ({how}): read-only {}{}, system libraries; writes nowhere",
        assets.display(),
        policy_file
            .map(|p| format!(", {}", p.display()))
            .unwrap_or_default()
    );
    let net = if abi >= 4 && enforced {
        let d = if ports.is_empty() {
            "no TCP connect or bind at all".to_string()
        } else {
            format!(
                "TCP connect only to port {} (endpoint) and 53 (DNS); no bind",
                ports[0]
            )
        };
        mech(names::LANDLOCK_NET, true, d)
    } else {
        mech(
            names::LANDLOCK_NET,
            false,
            format!("kernel landlock ABI v{abi} < 4 has no TCP rules"),
        )
    };
    let scope = if abi >= 6 && enforced {
        mech(
            names::LANDLOCK_SCOPE,
            true,
            "no signals to, and no abstract unix sockets of, processes outside the sandbox",
        )
    } else {
        mech(
            names::LANDLOCK_SCOPE,
            false,
            format!("kernel landlock ABI v{abi} < 6 has no scoping"),
        )
    };
    Ok(vec![
        mech(names::LANDLOCK_FS, enforced, fs_detail),
        net,
        scope,
    ])
}

/// System calls denied outright (EPERM). Process creation, debugging other
/// processes, kernel/module/mount/namespace administration, and kernel attack
/// surface a policy evaluation never needs (bpf, io_uring, userfaultfd, perf).
const DENIED: &[(libc::c_long, &str)] = &[
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
fn clone3_filter() -> Result<BpfProgram, SandboxError> {
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

fn apply_seccomp(network_allowed: bool) -> Result<SandboxMechanism, SandboxError> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_are_formatted_for_humans() {
        assert_eq!(format_bytes(4 << 30), "4 GiB");
        assert_eq!(format_bytes(512 << 20), "512 MiB");
        assert_eq!(format_bytes(64 << 20), "64 MiB");
        assert_eq!(format_bytes(1536 << 20), "1.50 GiB");
        assert_eq!(format_bytes(100), "100 bytes");
    }

    #[test]
    fn filters_compile_for_this_architecture() {
        let deny = deny_filter(false).expect("deny filter");
        assert!(
            deny.len() > DENIED.len(),
            "one check per denied syscall at least"
        );
        let deny_net = deny_filter(true).expect("deny filter (network)");
        assert!(
            deny_net.len() < deny.len(),
            "the socket rule is only there for file policies"
        );
        clone3_filter().expect("clone3 filter");
    }

    #[test]
    fn endpoint_port_defaults_by_scheme() {
        assert_eq!(endpoint_port("ws://example.org/x"), Some(80));
        assert_eq!(endpoint_port("wss://example.org"), Some(443));
        assert_eq!(endpoint_port("ws://127.0.0.1:9001"), Some(9001));
        assert_eq!(endpoint_port("not a url"), None);
    }
}
