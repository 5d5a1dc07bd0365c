//! Remote endpoint URL validation against server-side request forgery:
//! only ws/wss, a real host, and unless the job allows it no address in the
//! loopback, link-local, private, shared (CGNAT) or otherwise special ranges.
//! The host is resolved first and *every* address is checked, so a name that
//! resolves to both a public and a private address is refused.

use d3il_protocol::address::{resolve_public, AddressError};
use d3il_protocol::{ErrorKind, WorkerError};
use std::net::SocketAddr;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EndpointError {
    #[error("the endpoint URL `{url}` is not a valid URL ({reason}); use e.g. wss://policy.example.org:9000/")]
    Parse { url: String, reason: String },
    #[error("the endpoint URL scheme `{0}` is not allowed; use ws:// or wss://")]
    Scheme(String),
    #[error("the endpoint URL `{0}` has no host; use e.g. wss://policy.example.org:9000/")]
    NoHost(String),
    #[error("the endpoint URL must not contain a user name or password")]
    Credentials,
    /// Unresolvable, or an address in a refused range
    /// (`d3il_protocol::address`, the one classifier).
    #[error(transparent)]
    Address(#[from] AddressError),
}

impl From<EndpointError> for WorkerError {
    fn from(e: EndpointError) -> Self {
        WorkerError {
            kind: ErrorKind::BadEndpoint,
            message: e.to_string(),
        }
    }
}

/// Check `url` and resolve its host. Returns every address it resolves to (all
/// allowed). `allow_private` (Limits::allow_private_endpoints) admits loopback,
/// link-local and private ranges (`d3il eval`, and servers of trusted set-ups
/// started with `--allow-private-endpoints`); unspecified,
/// multicast and broadcast addresses are refused even then.
pub fn validate_endpoint(url: &str, allow_private: bool) -> Result<Vec<SocketAddr>, EndpointError> {
    let parsed = url::Url::parse(url).map_err(|e| EndpointError::Parse {
        url: truncate(url),
        reason: e.to_string(),
    })?;
    match parsed.scheme() {
        "ws" | "wss" => {}
        other => return Err(EndpointError::Scheme(truncate(other))),
    }
    if !parsed.username().is_empty() || parsed.password().is_some() {
        return Err(EndpointError::Credentials);
    }
    let host = match parsed.host_str() {
        Some(h) if !h.is_empty() => h,
        _ => return Err(EndpointError::NoHost(truncate(url))),
    };
    // url always knows ws=80, wss=443.
    let port = parsed.port_or_known_default().unwrap_or(80);
    Ok(resolve_public(host, port, allow_private)?)
}

fn truncate(s: &str) -> String {
    const MAX: usize = 200;
    if s.len() <= MAX {
        return s.to_string();
    }
    let mut end = MAX;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}…", &s[..end])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schemes_other_than_ws_are_refused() {
        for u in [
            "http://example.org/",
            "file:///etc/passwd",
            "gopher://x",
            "ftp://1.1.1.1",
        ] {
            let e = validate_endpoint(u, true).unwrap_err();
            assert!(matches!(e, EndpointError::Scheme(_)), "{u}: {e}");
        }
        assert!(matches!(
            validate_endpoint("no scheme here", true).unwrap_err(),
            EndpointError::Parse { .. }
        ));
        assert!(matches!(
            validate_endpoint("ws://user:pw@8.8.8.8/", true).unwrap_err(),
            EndpointError::Credentials
        ));
    }

    #[test]
    fn private_ranges_are_refused_unless_allowed() {
        for u in [
            "ws://127.0.0.1:9000/",
            "ws://127.8.9.10/",
            "ws://10.1.2.3/",
            "ws://172.16.0.1/",
            "ws://172.31.255.255/",
            "ws://192.168.1.1/",
            "ws://169.254.169.254/latest/meta-data",
            "ws://100.64.0.1/",
            "ws://[::1]:80/",
            "ws://[fd00::1]/",
            "ws://[fe80::1]/",
            "ws://[::ffff:127.0.0.1]/",
            "ws://[::127.0.0.1]/",
            "ws://[::ffff:0:127.0.0.1]/",
            "ws://[64:ff9b::a00:1]/",
            "ws://[64:ff9b:1::a00:1]/",
            "ws://[2002:7f00:1::1]/",
            "ws://[2001:0:7f00:1::1]/",
            "ws://localhost:9000/",
        ] {
            let e = validate_endpoint(u, false).unwrap_err();
            assert!(
                matches!(e, EndpointError::Address(AddressError::Forbidden { .. })),
                "{u}: {e:?}"
            );
            let msg = e.to_string();
            assert!(msg.contains("public addresses"), "{msg}");
            assert!(msg.contains("--allow-private-endpoints"), "{msg}");
        }
        let ok = validate_endpoint("ws://127.0.0.1:9000/", true).unwrap();
        assert_eq!(ok, vec!["127.0.0.1:9000".parse().unwrap()]);
        let ok = validate_endpoint("ws://localhost:9000/", true).unwrap();
        assert!(ok.iter().all(|a| a.ip().is_loopback() && a.port() == 9000));
    }

    #[test]
    fn special_addresses_are_refused_even_when_private_is_allowed() {
        for u in [
            "ws://0.0.0.0/",
            "ws://224.0.0.1/",
            "ws://255.255.255.255/",
            "ws://[::]/",
        ] {
            let e = validate_endpoint(u, true).unwrap_err();
            assert!(
                matches!(e, EndpointError::Address(AddressError::Unreachable { .. })),
                "{u}: {e:?}"
            );
        }
    }

    #[test]
    fn public_addresses_pass_without_resolving() {
        // Literal addresses need no DNS (this machine has none).
        let a = validate_endpoint("wss://8.8.8.8/policy", false).unwrap();
        assert_eq!(a, vec!["8.8.8.8:443".parse().unwrap()]);
        let a = validate_endpoint("ws://[2001:4860:4860::8888]:9000", false).unwrap();
        assert_eq!(a[0].port(), 9000);
        assert!(validate_endpoint("ws://172.32.0.1/", false).is_ok());
        assert!(validate_endpoint("ws://100.128.0.1/", false).is_ok());
    }

    #[test]
    fn unresolvable_hosts_are_a_bad_endpoint() {
        let e = validate_endpoint("ws://does-not-exist.invalid/", false).unwrap_err();
        assert!(
            matches!(e, EndpointError::Address(AddressError::Resolve { .. })),
            "{e:?}"
        );
        let w: WorkerError = e.into();
        assert_eq!(w.kind, ErrorKind::BadEndpoint);
    }
}
