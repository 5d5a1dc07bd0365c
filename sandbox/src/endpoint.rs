//! Remote endpoint URL validation against server-side request forgery (issue 6):
//! only ws/wss, a real host, and unless the job allows it no address in the
//! loopback, link-local, private, shared (CGNAT) or otherwise special ranges.
//! The host is resolved first and *every* address is checked, so a name that
//! resolves to both a public and a private address is refused.

use d3il_protocol::{ErrorKind, WorkerError};
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, ToSocketAddrs};

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
    #[error("the endpoint host `{host}` could not be resolved ({reason}); check the host name and its DNS records")]
    Resolve { host: String, reason: String },
    #[error(
        "the endpoint host `{host}` resolves to {addr}, which is in the {range} range; \
         the evaluator only connects to public addresses"
    )]
    Forbidden {
        host: String,
        addr: IpAddr,
        range: &'static str,
    },
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
/// link-local and private ranges, for tests and trusted set-ups; unspecified,
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
    let host = match parsed.host() {
        Some(h) => h,
        None => return Err(EndpointError::NoHost(truncate(url))),
    };
    // url always knows ws=80, wss=443.
    let port = parsed.port_or_known_default().unwrap_or(80);
    let host_str = host.to_string();
    let addrs: Vec<SocketAddr> = match host {
        url::Host::Ipv4(ip) => vec![SocketAddr::new(IpAddr::V4(ip), port)],
        url::Host::Ipv6(ip) => vec![SocketAddr::new(IpAddr::V6(ip), port)],
        url::Host::Domain(d) => (d, port)
            .to_socket_addrs()
            .map_err(|e| EndpointError::Resolve {
                host: truncate(d),
                reason: e.to_string(),
            })?
            .collect(),
    };
    if addrs.is_empty() {
        return Err(EndpointError::Resolve {
            host: truncate(&host_str),
            reason: "no addresses".into(),
        });
    }
    for a in &addrs {
        if let Some(range) = special_range(a.ip()) {
            let always = matches!(range, "unspecified" | "multicast" | "broadcast");
            if always || !allow_private {
                return Err(EndpointError::Forbidden {
                    host: truncate(&host_str),
                    addr: a.ip(),
                    range,
                });
            }
        }
    }
    Ok(addrs)
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

/// The name of the non-public range `ip` is in, if any.
pub fn special_range(ip: IpAddr) -> Option<&'static str> {
    match ip {
        IpAddr::V4(v4) => special_v4(v4),
        IpAddr::V6(v6) => special_v6(v6),
    }
}

fn special_v4(ip: Ipv4Addr) -> Option<&'static str> {
    let o = ip.octets();
    Some(match o {
        [0, ..] => "unspecified",
        [127, ..] => "loopback",
        [10, ..] => "private",
        [172, b, ..] if (16..32).contains(&b) => "private",
        [192, 168, ..] => "private",
        [169, 254, ..] => "link-local",
        [100, b, ..] if (64..128).contains(&b) => "shared (carrier-grade NAT)",
        [192, 0, 0, _] => "IETF protocol assignment",
        [198, b, ..] if b == 18 || b == 19 => "benchmarking",
        [255, 255, 255, 255] => "broadcast",
        [a, ..] if (224..240).contains(&a) => "multicast",
        [a, ..] if a >= 240 => "reserved",
        _ => return None,
    })
}

fn special_v6(ip: Ipv6Addr) -> Option<&'static str> {
    if ip.is_unspecified() {
        return Some("unspecified");
    }
    if ip.is_loopback() {
        return Some("loopback");
    }
    // IPv4-mapped (::ffff:a.b.c.d) and NAT64 (64:ff9b::a.b.c.d) reach v4 hosts.
    if let Some(v4) = ip.to_ipv4_mapped() {
        return special_v4(v4);
    }
    let s = ip.segments();
    if s[0] == 0x64 && s[1] == 0xff9b && s[2..6].iter().all(|&x| x == 0) {
        let v4 = Ipv4Addr::new((s[6] >> 8) as u8, s[6] as u8, (s[7] >> 8) as u8, s[7] as u8);
        return special_v4(v4);
    }
    match s[0] {
        x if x & 0xfe00 == 0xfc00 => Some("private (unique local)"),
        x if x & 0xffc0 == 0xfe80 => Some("link-local"),
        x if x & 0xffc0 == 0xfec0 => Some("site-local"),
        x if x & 0xff00 == 0xff00 => Some("multicast"),
        _ => None,
    }
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
            "ws://[64:ff9b::a00:1]/",
            "ws://localhost:9000/",
        ] {
            let e = validate_endpoint(u, false).unwrap_err();
            assert!(matches!(e, EndpointError::Forbidden { .. }), "{u}: {e:?}");
            let msg = e.to_string();
            assert!(msg.contains("public addresses"), "{msg}");
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
            assert!(matches!(e, EndpointError::Forbidden { .. }), "{u}: {e:?}");
        }
    }

    #[test]
    fn public_addresses_pass_without_resolving() {
        // Literal addresses need no DNS (this machine has none).
        let a = validate_endpoint("wss://8.8.8.8/policy", false).unwrap();
        assert_eq!(a, vec!["8.8.8.8:443".parse().unwrap()]);
        let a = validate_endpoint("ws://[2001:4860:4860::8888]:9000", false).unwrap();
        assert_eq!(a[0].port(), 9000);
        assert_eq!(special_range("172.32.0.1".parse().unwrap()), None);
        assert_eq!(special_range("100.128.0.1".parse().unwrap()), None);
    }

    #[test]
    fn unresolvable_hosts_are_a_bad_endpoint() {
        let e = validate_endpoint("ws://does-not-exist.invalid/", false).unwrap_err();
        assert!(matches!(e, EndpointError::Resolve { .. }), "{e:?}");
        let w: WorkerError = e.into();
        assert_eq!(w.kind, ErrorKind::BadEndpoint);
    }
}
