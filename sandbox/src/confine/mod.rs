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
//! reported inactive with the reason, never silently skipped.
//!
//! One file per mechanism: [`rlimits`], [`netns`], [`capabilities`],
//! [`landlock`] and [`seccomp`]; the system calls they make are the reason
//! this module may use `unsafe` (each block says why it is sound).

mod capabilities;
mod landlock;
mod netns;
mod rlimits;
mod seccomp;

use self::landlock::apply_landlock;
pub use self::landlock::landlock_abi;
use self::seccomp::apply_seccomp;
use capabilities::drop_capabilities;
use netns::enter_network_namespace;
use rlimits::apply_rlimits;

use d3il_protocol::{Job, PolicySource, SandboxMechanism};
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

/// Confine the calling process for `job`. `policy_files` are the files besides
/// the assets that the worker may read (the ONNX files: one, or a race job's
/// two); empty for remote or scripted policies.
///
/// Returns the mechanisms with whether each is in force. Errors only when a
/// mechanism that the kernel supports failed to apply (then the worker must not
/// go on, exit code `SANDBOX_FAILED`).
pub fn confine(job: &Job, policy_files: &[&Path]) -> Result<Vec<SandboxMechanism>, SandboxError> {
    // Landlock and seccomp apply to the calling thread (and threads it creates
    // later); unshare(CLONE_NEWNET) too. A thread started earlier would escape.
    let threads = thread_count();
    if threads > 1 {
        return Err(SandboxError::Multithreaded(threads));
    }
    for p in policy_files {
        // Fail with a clear message now rather than with EACCES later.
        std::fs::File::open(p).map_err(|source| SandboxError::PolicyFile {
            path: p.to_path_buf(),
            source,
        })?;
    }
    // A race job has a second policy: B's endpoint needs the
    // network as A's would.
    let policies: Vec<&PolicySource> = std::iter::once(&job.policy)
        .chain(job.kind.race().map(|r| &r.policy_b))
        .collect();
    let network_allowed = policies
        .iter()
        .any(|p| matches!(p, PolicySource::Remote { .. }));
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
    let connect_ports: Vec<u16> = policies
        .iter()
        .filter_map(|p| match p {
            PolicySource::Remote { url, .. } => endpoint_port(url),
            _ => None,
        })
        .collect();
    let rendering = job.manifest.obs_type == d3il_protocol::ObsType::Image;
    out.extend(apply_landlock(
        Path::new(&job.assets_dir),
        policy_files,
        network_allowed,
        &connect_ports,
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

#[cfg(test)]
mod tests {
    use super::seccomp::{clone3_filter, deny_filter, DENIED};
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
