//! The one private-address classifier, used by the
//! server's intake, the sandboxed worker's endpoint check and the remote-policy
//! client, so that all three refuse the same addresses.
//!
//! The rule, stated once: an endpoint host is refused if **any** address it
//! names or resolves to is in a non-public range ([`special_range`]). Ranges
//! marked [`SpecialRange::always_refused`] (unspecified, multicast, broadcast)
//! are refused even when private endpoints are allowed
//! (`Limits::allow_private_endpoints`: always in `d3il eval`, which connects
//! to whatever its user names on their own machine and network; in a server
//! only when its operator passes `--allow-private-endpoints`). Every refusal
//! the setting would lift names it ([`ALLOW_PRIVATE_SETTING`]).
//!
//! Every IPv6 form that reaches an IPv4 host is judged by the IPv4 address it
//! carries: IPv4-compatible `::a.b.c.d`, IPv4-mapped `::ffff:a.b.c.d`,
//! IPv4-translated `::ffff:0:a.b.c.d`, NAT64 `64:ff9b::/96`, 6to4 `2002::/16`
//! and both addresses inside a Teredo `2001::/32` address. Forms that carry a
//! public IPv4 address but are not routed on the public internet
//! (IPv4-compatible, local-use NAT64 `64:ff9b:1::/48`, Teredo) are refused as
//! such.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, ToSocketAddrs};

/// A non-public address range.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SpecialRange {
    /// A human name for the range, e.g. `loopback` or `private (unique local)`.
    pub name: &'static str,
    /// Refused even when private endpoints are allowed (no host can be
    /// reached there: unspecified, multicast, broadcast).
    pub always_refused: bool,
}

impl SpecialRange {
    const fn local(name: &'static str) -> Self {
        SpecialRange {
            name,
            always_refused: false,
        }
    }
    const fn never(name: &'static str) -> Self {
        SpecialRange {
            name,
            always_refused: true,
        }
    }
}

/// The setting that lets a server evaluate endpoints on loopback and private
/// addresses, named by every refusal it can lift (intake, dry run, worker,
/// remote client). `d3il eval` on the user's own machine always has it.
pub const ALLOW_PRIVATE_SETTING: &str = "a server evaluates submitted endpoints only on public \
     addresses unless its operator starts `d3il serve` (and each `d3il workers` host) with \
     `--allow-private-endpoints`; use a public host, or ask the operator of a trusted set-up \
     to set it (`d3il eval --policy ws://…` on your own machine needs no setting)";

/// Why an endpoint host is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AddressError {
    #[error("the endpoint host `{host}` could not be resolved ({reason}); check the host name and its DNS records")]
    Resolve { host: String, reason: String },
    /// A loopback, private or reserved address: refused unless private
    /// endpoints are allowed.
    #[error(
        "the endpoint host `{host}` resolves to {addr}, which is in the {range} range \
         (loopback/private/reserved); {setting}",
        setting = ALLOW_PRIVATE_SETTING
    )]
    Forbidden {
        host: String,
        addr: IpAddr,
        range: &'static str,
    },
    /// An address no policy server can be reached at (unspecified,
    /// multicast, broadcast): refused even when private endpoints are allowed.
    #[error(
        "the endpoint host `{host}` resolves to {addr}, a {range} address, which no policy \
         server can be reached at (a server listening on 0.0.0.0 or :: is reached at \
         127.0.0.1, ::1 or the machine's own address); use the server's own address"
    )]
    Unreachable {
        host: String,
        addr: IpAddr,
        range: &'static str,
    },
    #[error(
        "the endpoint host `{host}` is a loopback name; {setting}",
        setting = ALLOW_PRIVATE_SETTING
    )]
    LoopbackName { host: String },
}

/// The non-public range `ip` is in, if any.
pub fn special_range(ip: IpAddr) -> Option<SpecialRange> {
    match ip {
        IpAddr::V4(v4) => special_v4(v4),
        IpAddr::V6(v6) => special_v6(v6),
    }
}

/// The range that makes `ip` refused under the rule above, if any.
pub fn refused_range(ip: IpAddr, allow_private: bool) -> Option<&'static str> {
    special_range(ip)
        .filter(|r| r.always_refused || !allow_private)
        .map(|r| r.name)
}

/// Check every address of `host` (already resolved to `addrs`): the first
/// refused one is the error. An empty list is a resolution error.
pub fn check_addresses(
    host: &str,
    addrs: &[IpAddr],
    allow_private: bool,
) -> Result<(), AddressError> {
    if addrs.is_empty() {
        return Err(AddressError::Resolve {
            host: truncate(host),
            reason: "no addresses".into(),
        });
    }
    for &addr in addrs {
        let Some(range) = special_range(addr) else {
            continue;
        };
        if range.always_refused {
            return Err(AddressError::Unreachable {
                host: truncate(host),
                addr,
                range: range.name,
            });
        }
        if !allow_private {
            return Err(AddressError::Forbidden {
                host: truncate(host),
                addr,
                range: range.name,
            });
        }
    }
    Ok(())
}

/// Resolve `host` (a name or an IP literal, IPv6 with or without brackets)
/// and check every address it resolves to. Returns all of them (all allowed),
/// so the caller connects to a checked address without a second lookup.
pub fn resolve_public(
    host: &str,
    port: u16,
    allow_private: bool,
) -> Result<Vec<SocketAddr>, AddressError> {
    let bare = host.trim_start_matches('[').trim_end_matches(']');
    let addrs: Vec<SocketAddr> = match bare.parse::<IpAddr>() {
        Ok(ip) => vec![SocketAddr::new(ip, port)],
        Err(_) => (bare, port)
            .to_socket_addrs()
            .map_err(|e| AddressError::Resolve {
                host: truncate(bare),
                reason: e.to_string(),
            })?
            .collect(),
    };
    let ips: Vec<IpAddr> = addrs.iter().map(|a| a.ip()).collect();
    check_addresses(bare, &ips, allow_private)?;
    Ok(addrs)
}

/// The check that needs no DNS (the server's intake): a loopback name
/// (`localhost`, `*.localhost`) or an IP literal in a refused range. Names
/// are left to the worker, which resolves them and calls [`resolve_public`].
pub fn check_host_literal(host: &str, allow_private: bool) -> Result<(), AddressError> {
    let bare = host.trim_start_matches('[').trim_end_matches(']');
    if let Ok(ip) = bare.parse::<IpAddr>() {
        return check_addresses(bare, &[ip], allow_private);
    }
    let name = bare.trim_end_matches('.').to_ascii_lowercase();
    if !allow_private && (name == "localhost" || name.ends_with(".localhost")) {
        return Err(AddressError::LoopbackName {
            host: truncate(bare),
        });
    }
    Ok(())
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

fn special_v4(ip: Ipv4Addr) -> Option<SpecialRange> {
    let o = ip.octets();
    Some(match o {
        [0, ..] => SpecialRange::never("unspecified"),
        [255, 255, 255, 255] => SpecialRange::never("broadcast"),
        [a, ..] if (224..240).contains(&a) => SpecialRange::never("multicast"),
        [127, ..] => SpecialRange::local("loopback"),
        [10, ..] => SpecialRange::local("private"),
        [172, b, ..] if (16..32).contains(&b) => SpecialRange::local("private"),
        [192, 168, ..] => SpecialRange::local("private"),
        [169, 254, ..] => SpecialRange::local("link-local"),
        [100, b, ..] if (64..128).contains(&b) => SpecialRange::local("shared (carrier-grade NAT)"),
        [192, 0, 0, _] => SpecialRange::local("IETF protocol assignment"),
        [192, 0, 2, _] | [198, 51, 100, _] | [203, 0, 113, _] => {
            SpecialRange::local("documentation")
        }
        [192, 88, 99, _] => SpecialRange::local("6to4 relay anycast"),
        [198, b, ..] if b == 18 || b == 19 => SpecialRange::local("benchmarking"),
        [a, ..] if a >= 240 => SpecialRange::local("reserved"),
        _ => return None,
    })
}

fn v4_at(s: &[u16; 8], i: usize) -> Ipv4Addr {
    Ipv4Addr::new(
        (s[i] >> 8) as u8,
        s[i] as u8,
        (s[i + 1] >> 8) as u8,
        s[i + 1] as u8,
    )
}

fn special_v6(ip: Ipv6Addr) -> Option<SpecialRange> {
    let s = ip.segments();
    if ip.is_unspecified() {
        return Some(SpecialRange::never("unspecified"));
    }
    if ip.is_loopback() {
        return Some(SpecialRange::local("loopback"));
    }
    // ::a.b.c.d (IPv4-compatible, deprecated; some stacks still route it to
    // the IPv4 host).
    if s[..6] == [0; 6] {
        return special_v4(v4_at(&s, 6))
            .or(Some(SpecialRange::local("IPv4-compatible (deprecated)")));
    }
    // ::ffff:a.b.c.d (IPv4-mapped) reaches the IPv4 host itself.
    if s[..5] == [0; 5] && s[5] == 0xffff {
        return special_v4(v4_at(&s, 6));
    }
    // ::ffff:0:a.b.c.d (IPv4-translated, SIIT).
    if s[..4] == [0; 4] && s[4] == 0xffff && s[5] == 0 {
        return special_v4(v4_at(&s, 6));
    }
    // 64:ff9b::a.b.c.d (well-known NAT64 prefix) reaches the IPv4 host.
    if s[0] == 0x64 && s[1] == 0xff9b && s[2..6] == [0; 4] {
        return special_v4(v4_at(&s, 6));
    }
    // 64:ff9b:1::/48 (local-use NAT64, RFC 8215): a site's own translator.
    if s[0] == 0x64 && s[1] == 0xff9b && s[2] == 1 {
        return Some(SpecialRange::local("local-use NAT64"));
    }
    // 2002:a.b.c.d::/48 (6to4) tunnels to the IPv4 host a.b.c.d.
    if s[0] == 0x2002 {
        return special_v4(v4_at(&s, 1));
    }
    // 2001:0::/32 (Teredo): the server's IPv4 address, then the client's,
    // bit-inverted. Either one private means the packet goes there; a public
    // Teredo address is still a tunnel, not a policy server.
    if s[0] == 0x2001 && s[1] == 0 {
        let server = v4_at(&s, 2);
        let client = Ipv4Addr::from(!u32::from(v4_at(&s, 6)));
        return special_v4(server)
            .or(special_v4(client))
            .or(Some(SpecialRange::local("Teredo tunnel")));
    }
    Some(match s[0] {
        x if x & 0xff00 == 0xff00 => SpecialRange::never("multicast"),
        x if x & 0xfe00 == 0xfc00 => SpecialRange::local("private (unique local)"),
        x if x & 0xffc0 == 0xfe80 => SpecialRange::local("link-local"),
        x if x & 0xffc0 == 0xfec0 => SpecialRange::local("site-local (deprecated)"),
        0x2001 if s[1] == 0xdb8 => SpecialRange::local("documentation"),
        x if x & 0xfff0 == 0x3ff0 => SpecialRange::local("documentation"),
        0x2001 if s[1] == 2 && s[2] == 0 => SpecialRange::local("benchmarking"),
        0x2001 if (0x10..0x30).contains(&s[1]) => SpecialRange::local("ORCHID"),
        0x100 if s[1..4] == [0; 3] => SpecialRange::local("discard-only"),
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn range(a: &str) -> Option<&'static str> {
        special_range(a.parse().unwrap()).map(|r| r.name)
    }

    #[test]
    fn ipv4_special_ranges() {
        for (a, want) in [
            ("0.0.0.0", "unspecified"),
            ("127.0.0.1", "loopback"),
            ("127.8.9.10", "loopback"),
            ("10.1.2.3", "private"),
            ("172.16.0.1", "private"),
            ("172.31.255.255", "private"),
            ("192.168.1.1", "private"),
            ("169.254.169.254", "link-local"),
            ("100.64.0.1", "shared (carrier-grade NAT)"),
            ("192.0.0.8", "IETF protocol assignment"),
            ("192.0.2.1", "documentation"),
            ("198.51.100.7", "documentation"),
            ("203.0.113.9", "documentation"),
            ("198.18.0.1", "benchmarking"),
            ("224.0.0.1", "multicast"),
            ("255.255.255.255", "broadcast"),
            ("240.0.0.1", "reserved"),
        ] {
            assert_eq!(range(a), Some(want), "{a}");
        }
        for a in [
            "8.8.8.8",
            "1.1.1.1",
            "172.32.0.1",
            "100.128.0.1",
            "11.0.0.1",
        ] {
            assert_eq!(range(a), None, "{a}");
        }
    }

    #[test]
    fn ipv6_native_special_ranges() {
        for (a, want) in [
            ("::", "unspecified"),
            ("::1", "loopback"),
            ("fd00::1", "private (unique local)"),
            ("fc12:3456::1", "private (unique local)"),
            ("fe80::1", "link-local"),
            ("febf::1", "link-local"),
            ("fec0::1", "site-local (deprecated)"),
            ("ff02::1", "multicast"),
            ("2001:db8::1", "documentation"),
            ("3fff::1", "documentation"),
            ("2001:2::1", "benchmarking"),
            ("2001:20::1", "ORCHID"),
            ("100::1", "discard-only"),
        ] {
            assert_eq!(range(a), Some(want), "{a}");
        }
        for a in ["2001:4860:4860::8888", "2606:4700::1111", "2a00:1450::1"] {
            assert_eq!(range(a), None, "{a}");
        }
    }

    #[test]
    fn ipv4_compatible_is_judged_by_its_ipv4_address() {
        assert_eq!(range("::127.0.0.1"), Some("loopback"));
        assert_eq!(range("::10.0.0.1"), Some("private"));
        assert_eq!(range("::169.254.169.254"), Some("link-local"));
        // A public IPv4 inside is still not a routed IPv6 address.
        assert_eq!(range("::8.8.8.8"), Some("IPv4-compatible (deprecated)"));
    }

    #[test]
    fn ipv4_mapped_and_translated_are_judged_by_their_ipv4_address() {
        assert_eq!(range("::ffff:127.0.0.1"), Some("loopback"));
        assert_eq!(range("::ffff:192.168.0.1"), Some("private"));
        assert_eq!(range("::ffff:0.0.0.0"), Some("unspecified"));
        assert_eq!(range("::ffff:8.8.8.8"), None);
        assert_eq!(range("::ffff:0:127.0.0.1"), Some("loopback"));
        assert_eq!(range("::ffff:0:10.1.1.1"), Some("private"));
        assert_eq!(range("::ffff:0:8.8.8.8"), None);
    }

    #[test]
    fn nat64_is_judged_by_its_ipv4_address() {
        assert_eq!(range("64:ff9b::127.0.0.1"), Some("loopback"));
        assert_eq!(range("64:ff9b::a00:1"), Some("private"));
        assert_eq!(range("64:ff9b::a9fe:a9fe"), Some("link-local"));
        assert_eq!(range("64:ff9b::808:808"), None);
        // Local-use NAT64 (RFC 8215) is a site's own translator: never public.
        assert_eq!(range("64:ff9b:1::808:808"), Some("local-use NAT64"));
        assert_eq!(range("64:ff9b:1:abcd::1"), Some("local-use NAT64"));
    }

    #[test]
    fn six_to_four_is_judged_by_its_ipv4_address() {
        // 2002:AABB:CCDD::/48 tunnels to AA.BB.CC.DD.
        assert_eq!(range("2002:7f00:1::1"), Some("loopback"));
        assert_eq!(range("2002:c0a8:101::"), Some("private"));
        assert_eq!(range("2002:a9fe:a9fe::1"), Some("link-local"));
        assert_eq!(range("2002:e000:1::1"), Some("multicast"));
        assert_eq!(range("2002:808:808::1"), None);
    }

    #[test]
    fn teredo_is_refused_and_names_a_private_ipv4_inside() {
        // Server 127.0.0.1 in bits 32..64.
        assert_eq!(range("2001:0:7f00:1::1"), Some("loopback"));
        // Client 10.0.0.1 stored bit-inverted: !0x0a000001 = 0xf5fffffe.
        assert_eq!(range("2001:0:808:808:0:0:f5ff:fffe"), Some("private"));
        // Both public: still a tunnel.
        assert_eq!(range("2001:0:808:808:0:0:f7f7:f7f7"), Some("Teredo tunnel"));
    }

    #[test]
    fn the_rule_refuses_if_any_address_is_special() {
        let public: IpAddr = "8.8.8.8".parse().unwrap();
        let private: IpAddr = "10.0.0.1".parse().unwrap();
        let multicast: IpAddr = "ff02::1".parse().unwrap();
        assert!(check_addresses("h", &[public], false).is_ok());
        let e = check_addresses("h", &[public, private], false).unwrap_err();
        assert_eq!(
            e,
            AddressError::Forbidden {
                host: "h".into(),
                addr: private,
                range: "private"
            }
        );
        assert!(e.to_string().contains("public addresses"), "{e}");
        // The refusal names the setting that lifts it.
        assert!(
            e.to_string().contains("`d3il serve`")
                && e.to_string().contains("`--allow-private-endpoints`"),
            "{e}"
        );
        // Allowing private endpoints admits private but never multicast,
        // whose refusal names no setting (none would help).
        assert!(check_addresses("h", &[public, private], true).is_ok());
        let e = check_addresses("h", &[public, multicast], true).unwrap_err();
        assert!(
            matches!(
                e,
                AddressError::Unreachable {
                    range: "multicast",
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(!e.to_string().contains("--allow-private-endpoints"), "{e}");
        let e = check_addresses("h", &["0.0.0.0".parse().unwrap()], false).unwrap_err();
        assert!(e.to_string().contains("127.0.0.1"), "{e}");
        assert!(matches!(
            check_addresses("h", &[], true),
            Err(AddressError::Resolve { .. })
        ));
    }

    #[test]
    fn literals_and_loopback_names_need_no_dns() {
        for h in [
            "[::ffff:127.0.0.1]",
            "[::127.0.0.1]",
            "[64:ff9b::7f00:1]",
            "[2002:7f00:1::1]",
            "127.0.0.1",
            "localhost",
            "LocalHost.",
            "x.localhost",
        ] {
            let e = check_host_literal(h, false).unwrap_err();
            assert!(
                e.to_string().contains("--allow-private-endpoints"),
                "{h}: {e}"
            );
            assert!(check_host_literal(h, true).is_ok(), "{h}");
        }
        assert!(check_host_literal("[::]", true).is_err());
        assert!(check_host_literal("policy.example.org", false).is_ok());
        assert!(check_host_literal("[2001:4860:4860::8888]", false).is_ok());
    }

    #[test]
    fn resolve_public_checks_every_address() {
        let a = resolve_public("[2001:4860:4860::8888]", 9000, false).unwrap();
        assert_eq!(a, vec!["[2001:4860:4860::8888]:9000".parse().unwrap()]);
        assert!(matches!(
            resolve_public("::ffff:127.0.0.1", 80, false),
            Err(AddressError::Forbidden {
                range: "loopback",
                ..
            })
        ));
        // localhost resolves (from /etc/hosts) to loopback addresses only.
        assert!(matches!(
            resolve_public("localhost", 80, false),
            Err(AddressError::Forbidden {
                range: "loopback",
                ..
            })
        ));
        let ok = resolve_public("localhost", 80, true).unwrap();
        assert!(ok.iter().all(|a| a.ip().is_loopback()));
        assert!(matches!(
            resolve_public("does-not-exist.invalid", 80, false),
            Err(AddressError::Resolve { .. })
        ));
    }
}
