//! Every capability dropped when the worker runs as root.

use super::{mech, names, SandboxError};
use d3il_protocol::SandboxMechanism;

/// Root keeps uid 0 (file ownership checks) but loses every capability, so no
/// mount, raw socket, module loading, DAC override ...
pub(super) fn drop_capabilities() -> Result<SandboxMechanism, SandboxError> {
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
