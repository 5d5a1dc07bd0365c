//! The client's address behind a reverse proxy (`d3il serve --trusted-proxy`).
//!
//! Behind a proxy every connection comes from the proxy, so the per-address
//! rate limits would see one client. When the connection's peer is one of
//! the operator's trusted proxies, the client is read from
//! `X-Forwarded-For`: walking it from the right (each proxy appends the
//! address it received the request from), past the entries that are trusted
//! proxies themselves, the first address that is not is the client. Entries
//! left of it may be anything the client sent and are never used. From a
//! peer that is not trusted, the header is ignored: the peer is the client.

use axum::http::HeaderMap;
use ipnet::IpNet;
use std::net::IpAddr;

/// The client address of a request (the extension handlers and middleware
/// read; set for every request by `app::serve_listener`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClientAddr(pub IpAddr);

/// The proxies whose `X-Forwarded-For` is believed: addresses and networks.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct TrustedProxies(Vec<IpNet>);

/// One `--trusted-proxy` value: an address (`10.0.0.5`, `::1`) or a network
/// (`10.0.0.0/8`, `fd00::/8`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TrustedProxy(IpNet);

impl std::str::FromStr for TrustedProxy {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        if let Ok(ip) = s.parse::<IpAddr>() {
            return Ok(TrustedProxy(IpNet::from(unmapped(ip))));
        }
        s.parse::<IpNet>()
            .map(|n| TrustedProxy(n.trunc()))
            .map_err(|_| {
                format!(
                    "`{s}` is not an IP address or network; give the proxy's address \
                 (10.0.0.5, ::1) or its network (10.0.0.0/8, fd00::/8)"
                )
            })
    }
}

impl std::fmt::Display for TrustedProxy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            n if n.prefix_len() == n.max_prefix_len() => write!(f, "{}", n.addr()),
            n => write!(f, "{n}"),
        }
    }
}

impl FromIterator<TrustedProxy> for TrustedProxies {
    fn from_iter<I: IntoIterator<Item = TrustedProxy>>(it: I) -> Self {
        TrustedProxies(it.into_iter().map(|p| p.0).collect())
    }
}

impl TrustedProxies {
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Whether `ip` (an IPv4-mapped IPv6 address as its IPv4) is trusted.
    pub fn contains(&self, ip: IpAddr) -> bool {
        let ip = unmapped(ip);
        self.0.iter().any(|n| n.contains(&ip))
    }

    /// The list as given (`/admin`).
    pub fn describe(&self) -> Vec<String> {
        self.0
            .iter()
            .map(|n| TrustedProxy(*n).to_string())
            .collect()
    }

    /// The client address of a request from `peer` with `headers` (see the
    /// module documentation). An `X-Forwarded-For` entry that is not an
    /// address (`unknown`, a name) ends the walk at the last trusted hop.
    pub fn client_addr(&self, peer: IpAddr, headers: &HeaderMap) -> IpAddr {
        let mut client = unmapped(peer);
        if !self.contains(client) {
            return client;
        }
        // Several headers are one list, in order.
        let entries: Vec<&str> = headers
            .get_all("x-forwarded-for")
            .iter()
            .filter_map(|v| v.to_str().ok())
            .flat_map(|v| v.split(','))
            .map(str::trim)
            .collect();
        for entry in entries.into_iter().rev() {
            let Some(ip) = forwarded_ip(entry) else {
                break;
            };
            client = ip;
            if !self.contains(client) {
                break;
            }
        }
        client
    }
}

/// An `X-Forwarded-For` entry's address: `203.0.113.7`, `2001:db8::1`, or
/// with a port (`203.0.113.7:5100`, `[2001:db8::1]:5100`).
fn forwarded_ip(entry: &str) -> Option<IpAddr> {
    entry
        .parse::<IpAddr>()
        .ok()
        .or_else(|| entry.parse::<std::net::SocketAddr>().ok().map(|s| s.ip()))
        .map(unmapped)
}

fn unmapped(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(ip, IpAddr::V4),
        v4 => v4,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(s: &str) -> IpAddr {
        s.parse().unwrap()
    }

    fn proxies(list: &[&str]) -> TrustedProxies {
        list.iter()
            .map(|s| s.parse::<TrustedProxy>().unwrap())
            .collect()
    }

    fn xff(values: &[&str]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for v in values {
            h.append("x-forwarded-for", v.parse().unwrap());
        }
        h
    }

    #[test]
    fn the_right_most_untrusted_entry_from_a_trusted_peer() {
        let t = proxies(&["10.0.0.0/8", "192.0.2.1"]);
        let peer = ip("10.1.2.3");
        // The proxy appended the client; what the client sent is left of it.
        let h = xff(&["1.1.1.1, 203.0.113.7"]);
        assert_eq!(t.client_addr(peer, &h), ip("203.0.113.7"));
        // Two trusted proxies in a row, and the list split over two headers.
        let h = xff(&["6.6.6.6, 203.0.113.7", "192.0.2.1, 10.9.9.9"]);
        assert_eq!(t.client_addr(peer, &h), ip("203.0.113.7"));
        // Ports, IPv6 and IPv4-mapped entries.
        let h = xff(&["[2001:db8::1]:4000"]);
        assert_eq!(t.client_addr(peer, &h), ip("2001:db8::1"));
        let h = xff(&["203.0.113.8:4000"]);
        assert_eq!(t.client_addr(peer, &h), ip("203.0.113.8"));
        let h = xff(&["::ffff:203.0.113.9"]);
        assert_eq!(t.client_addr(ip("::ffff:10.0.0.1"), &h), ip("203.0.113.9"));
        // No header, or only trusted hops: the last one seen.
        assert_eq!(t.client_addr(peer, &HeaderMap::new()), peer);
        assert_eq!(t.client_addr(peer, &xff(&["10.0.0.7"])), ip("10.0.0.7"));
        // Garbage ends the walk at the last trusted hop.
        let h = xff(&["203.0.113.7, unknown"]);
        assert_eq!(t.client_addr(peer, &h), peer);
    }

    #[test]
    fn the_header_of_an_untrusted_peer_is_ignored() {
        let t = proxies(&["10.0.0.0/8"]);
        let h = xff(&["203.0.113.7"]);
        assert_eq!(t.client_addr(ip("198.51.100.4"), &h), ip("198.51.100.4"));
        assert_eq!(
            TrustedProxies::default().client_addr(ip("10.0.0.1"), &h),
            ip("10.0.0.1")
        );
    }

    #[test]
    fn proxies_parse_as_addresses_or_networks() {
        let t = proxies(&["127.0.0.1", "10.1.2.3/8", "fd00::/8", "::ffff:192.0.2.1"]);
        assert_eq!(
            t.describe(),
            ["127.0.0.1", "10.0.0.0/8", "fd00::/8", "192.0.2.1"]
        );
        assert!(t.contains(ip("10.200.0.1")) && t.contains(ip("fd12::1")));
        assert!(!t.contains(ip("11.0.0.1")));
        let e = "proxy.example".parse::<TrustedProxy>().unwrap_err();
        assert!(e.contains("not an IP address or network"), "{e}");
        assert!("10.0.0.0/33".parse::<TrustedProxy>().is_err());
    }
}
