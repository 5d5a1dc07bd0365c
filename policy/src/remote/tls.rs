//! `wss://`: the trust store (Mozilla's roots plus the operator's extra CA),
//! the TLS handshake under the connection's deadline, and a submitter-facing
//! explanation of every way it fails.

use super::transport::{DeadlineStream, Endpoint, Transport};
use crate::PolicyError;
use d3il_protocol::Limits;
use std::io;
use std::sync::Arc;
use std::time::Duration;

/// Run the TLS handshake on `stream` for `ep.host`.
pub(super) fn handshake(
    url: &str,
    ep: &Endpoint,
    stream: DeadlineStream,
    limits: &Limits,
    deadline: Duration,
) -> Result<Transport, PolicyError> {
    let host = &ep.host;
    // In a sandboxed worker the parent has put $D3IL_EXTRA_CA_FILE into
    // the job (and removed the variable); an unsandboxed run reads it here.
    let env_ca = match &limits.extra_ca_pem {
        Some(_) => None,
        None => Limits::extra_ca_from_env().map_err(PolicyError::Config)?,
    };
    let extra_ca = limits.extra_ca_pem.as_deref().or(env_ca.as_deref());
    let config = tls_config(extra_ca).map_err(PolicyError::Config)?;
    let name = rustls::pki_types::ServerName::try_from(host.clone()).map_err(|e| {
        PolicyError::BadEndpoint {
            url: url.into(),
            reason: format!("`{host}` is not a valid TLS server name ({e})"),
        }
    })?;
    let conn = rustls::ClientConnection::new(Arc::new(config), name).map_err(|e| {
        PolicyError::Connect {
            url: url.into(),
            reason: format!("TLS set-up failed: {e}"),
        }
    })?;
    let first_byte = Arc::clone(&stream.first_byte);
    let mut t = rustls::StreamOwned::new(conn, stream);
    while t.conn.is_handshaking() {
        if let Err(e) = t.conn.complete_io(&mut t.sock) {
            return Err(tls_error(e, url, host, deadline, first_byte.get().copied()));
        }
    }
    Ok(Transport::Tls(Box::new(t)))
}

/// First bytes of a TLS record a server sends: handshake (0x16) or alert (0x15).
pub(super) fn looks_like_tls(first: Option<u8>) -> bool {
    matches!(first, Some(0x15 | 0x16))
}

/// The trust store for `wss://`: Mozilla's roots compiled into the binary (the
/// sandboxed worker reads no CA file) plus the operator's extra CA, if any.
pub(super) fn tls_config(extra_ca_pem: Option<&str>) -> Result<rustls::ClientConfig, String> {
    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::CertificateDer;
    let mut roots = rustls::RootCertStore {
        roots: webpki_roots::TLS_SERVER_ROOTS.to_vec(),
    };
    if let Some(pem) = extra_ca_pem {
        let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(pem.as_bytes())
            .collect::<Result<_, _>>()
            .map_err(|e| {
                format!("the extra CA (extra_ca_pem / $D3IL_EXTRA_CA_FILE) is not valid PEM: {e}")
            })?;
        if certs.is_empty() {
            return Err(
                "the extra CA (extra_ca_pem / $D3IL_EXTRA_CA_FILE) holds no `-----BEGIN CERTIFICATE-----` block"
                    .into(),
            );
        }
        for c in certs {
            roots.add(c).map_err(|e| {
                format!("the extra CA (extra_ca_pem / $D3IL_EXTRA_CA_FILE) is not a usable CA certificate: {e}")
            })?;
        }
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    Ok(rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| format!("TLS set-up failed: {e}"))?
        .with_root_certificates(roots)
        .with_no_client_auth())
}

/// A submitter-facing explanation of a failed TLS handshake with `host`.
fn tls_error(
    e: io::Error,
    url: &str,
    host: &str,
    deadline: Duration,
    first_byte: Option<u8>,
) -> PolicyError {
    use rustls::{CertificateError as C, Error as R};
    if matches!(
        e.kind(),
        io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock
    ) {
        return PolicyError::Late {
            request: "TLS handshake".into(),
            deadline_ms: deadline.as_millis() as u64,
        };
    }
    let tls = |reason: String| PolicyError::Tls {
        url: url.into(),
        reason,
    };
    let Some(r) = e.get_ref().and_then(|i| i.downcast_ref::<R>()) else {
        return match e.kind() {
            io::ErrorKind::UnexpectedEof
            | io::ErrorKind::ConnectionReset
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::BrokenPipe => PolicyError::Connect {
                url: url.into(),
                reason: format!(
                    "the server closed the connection during the TLS handshake ({e}); if it serves plain WebSocket, use ws:// instead of wss://"
                ),
            },
            _ => PolicyError::Connect {
                url: url.into(),
                reason: format!("TLS handshake: {e}"),
            },
        };
    };
    match r {
        R::InvalidCertificate(c) => {
            let hint = match c {
                C::UnknownIssuer | C::BadSignature => "it is not signed by a publicly trusted CA (a self-signed or private-CA certificate?); use a certificate from a public CA such as Let's Encrypt and serve its full chain (intermediates included)".to_string(),
                C::NotValidForName | C::NotValidForNameContext { .. } => format!(
                    "it does not name `{host}`; serve a certificate whose subject alternative names include `{host}`, or use the host name the certificate is for in the URL"
                ),
                C::Expired | C::ExpiredContext { .. } => "it has expired; renew it".into(),
                C::NotValidYet | C::NotValidYetContext { .. } => {
                    "it is not valid yet (check the server's clock)".into()
                }
                _ => "serve a valid certificate from a public CA for this host".into(),
            };
            tls(format!(
                "the endpoint's TLS certificate is not valid for host `{host}`: {r}; {hint}"
            ))
        }
        R::InvalidMessage(_) | R::InappropriateHandshakeMessage { .. } | R::InappropriateMessage { .. }
            if !looks_like_tls(first_byte) =>
        {
            tls(format!(
                "the policy server at `{url}` did not answer with TLS ({r}); it seems to serve plain WebSocket: use ws:// instead of wss://, or serve TLS on this port"
            ))
        }
        other => tls(format!(
            "the TLS handshake with the policy server at `{url}` failed: {other}; serve TLS 1.2 or 1.3 with a certificate for `{host}` from a public CA"
        )),
    }
}
