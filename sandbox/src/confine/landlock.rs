//! Landlock: the read-only filesystem allow-list, the TCP connect/bind rules
//! and signal/abstract-socket scoping.

use super::{mech, names, SandboxError, EXTRA_READ_ENV};
use d3il_protocol::SandboxMechanism;
use landlock::{
    path_beneath_rules, Access, AccessFs, AccessNet, NetPort, Ruleset, RulesetAttr,
    RulesetCreatedAttr, RulesetStatus, Scope, ABI,
};
use std::path::{Path, PathBuf};

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

pub(super) fn apply_landlock(
    assets: &Path,
    policy_files: &[&Path],
    network_allowed: bool,
    connect_ports: &[u16],
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
    readable.extend(policy_files.iter().map(|p| p.to_path_buf()));
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
    let mut ports: Vec<u16> = Vec::new();
    for &port in connect_ports {
        if !ports.contains(&port) {
            ports.push(port);
        }
    }
    if !ports.is_empty() {
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
        policy_files
            .iter()
            .map(|p| format!(", {}", p.display()))
            .collect::<String>()
    );
    let net = if abi >= 4 && enforced {
        let d = if ports.is_empty() {
            "no TCP connect or bind at all".to_string()
        } else {
            let endpoints = &ports[..ports.len() - 1];
            let listed: Vec<String> = endpoints.iter().map(u16::to_string).collect();
            format!(
                "TCP connect only to port{} {} (endpoint{}) and 53 (DNS); no bind",
                if endpoints.len() > 1 { "s" } else { "" },
                listed.join(", "),
                if endpoints.len() > 1 { "s" } else { "" },
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
