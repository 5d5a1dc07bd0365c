//! A fresh, empty network namespace for file policies (no route anywhere,
//! not even to the host's loopback).

use super::{mech, names, SandboxError};
use d3il_protocol::SandboxMechanism;

/// A new, empty network namespace: only a loopback interface that is down, so
/// every connect (including to 127.0.0.1 on the host) fails with ENETUNREACH.
pub(super) fn enter_network_namespace() -> Result<SandboxMechanism, SandboxError> {
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
