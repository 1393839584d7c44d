//! Revoked certificates (docs/security.md, "Certificates: revoke"): a list
//! of SPIFFE identities and certificate serial numbers that every server
//! reads at start and again within [`crate::tls::RELOAD_INTERVAL`] of a
//! change, refuses at the TLS handshake, and for which it ends the calls
//! already running ([`RevocationLayer`]).
//!
//! Both kinds of entry, because they answer different losses: an identity
//! (`spiffe://vlnav/robot/husky-1`) refuses every certificate naming it,
//! issued before or after — a stolen robot, whatever certificates it holds,
//! until someone removes the entry; a serial refuses one certificate — a
//! leaked key, while the robot keeps working with a new certificate. A
//! certificate revocation list signed by the CA would carry only serials
//! and need the CA's key on every revocation.
//!
//! The file is TOML (`vlnav credentials revoke` writes it):
//!
//! ```toml
//! [[revoked]]
//! identity = "spiffe://vlnav/robot/husky-1"
//! reason = "lost"
//! revoked_unix = 1798761600.0
//!
//! [[revoked]]
//! serial = "4f0e…"   # hex, as `openssl x509 -serial` prints it, any case, ':' allowed
//! ```

use std::fmt;
use std::path::Path;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use anyhow::Context as _;
use bytes::Bytes;
use futures::future::BoxFuture;
use http_body::Frame;
use tokio::sync::watch;
use tonic::Status;
use tonic::body::Body;
use tonic::transport::server::{TcpConnectInfo, TlsConnectInfo};

use crate::authz::spiffe_ids;

/// One revoked identity or certificate.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Revoked {
    /// Every certificate naming this `spiffe://` identity.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub identity: Option<String>,
    /// The certificate with this serial number (hex).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial: Option<String>,
    /// Why, for the refusal's message and the log.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub reason: String,
    /// When it was revoked (seconds since the Unix epoch), for people.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub revoked_unix: Option<f64>,
}

/// The revoked identities and certificates a server refuses.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RevocationList {
    #[serde(default, rename = "revoked")]
    pub entries: Vec<Revoked>,
}

/// A serial number as lower-case hex without separators or leading zero
/// bytes, or `None` when `text` is no hex number.
pub fn normalize_serial(text: &str) -> Option<String> {
    let hex: String = text.trim().trim_start_matches("0x").chars().filter(|c| *c != ':').collect();
    if hex.is_empty() || !hex.chars().all(|c| c.is_ascii_hexdigit()) {
        return None;
    }
    let hex = hex.to_ascii_lowercase();
    let trimmed = hex.trim_start_matches('0');
    // Whole bytes, as certificates carry them.
    Some(if trimmed.is_empty() {
        "00".into()
    } else if trimmed.len() % 2 == 1 {
        format!("0{trimmed}")
    } else {
        trimmed.to_string()
    })
}

/// What a certificate is, as far as revocation is concerned.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CertificateId {
    /// Normalized ([`normalize_serial`]); empty when the DER does not parse.
    pub serial: String,
    /// Its `spiffe://` URI SANs.
    pub identities: Vec<String>,
}

impl CertificateId {
    /// Of a DER certificate.
    pub fn of(der: &[u8]) -> Self {
        let serial = x509_parser::parse_x509_certificate(der)
            .ok()
            .and_then(|(_, c)| normalize_serial(&c.raw_serial().iter().map(|b| format!("{b:02x}")).collect::<String>()))
            .unwrap_or_default();
        Self { serial, identities: spiffe_ids(der) }
    }

    /// Of the first certificate of a PEM file.
    pub fn of_pem_file(path: &Path) -> anyhow::Result<Self> {
        let pem = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        let der = crate::security::pem_to_der(&pem)
            .ok_or_else(|| anyhow::anyhow!("{} holds no PEM certificate", path.display()))?;
        let id = Self::of(&der);
        if id.serial.is_empty() {
            anyhow::bail!("{} is not an X.509 certificate", path.display());
        }
        Ok(id)
    }
}

impl fmt::Display for CertificateId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.identities.as_slice() {
            [] => write!(f, "the certificate with serial {}", self.serial),
            ids => write!(f, "the certificate of {} (serial {})", ids.join(" and "), self.serial),
        }
    }
}

impl RevocationList {
    /// Parses and checks a list: every entry names an identity or a serial.
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        let mut list: Self = toml::from_str(text).context("not a revocation list")?;
        for (i, e) in list.entries.iter_mut().enumerate() {
            let n = i + 1;
            match (&e.identity, &e.serial) {
                (None, None) => anyhow::bail!("entry {n} names neither an identity nor a serial"),
                (Some(id), _) if !id.starts_with("spiffe://") || id.len() <= "spiffe://".len() => {
                    anyhow::bail!("entry {n}: identity {id:?} is not a spiffe:// URI")
                }
                _ => {}
            }
            if let Some(s) = &e.serial {
                e.serial =
                    Some(normalize_serial(s).ok_or_else(|| anyhow::anyhow!("entry {n}: serial {s:?} is not hex"))?);
            }
        }
        Ok(list)
    }

    /// Reads `path`; a file that does not exist is an empty list.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        match std::fs::read_to_string(path) {
            Ok(text) => Self::parse(&text).with_context(|| format!("{}", path.display())),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Self::default()),
            Err(e) => Err(e).with_context(|| format!("cannot read {}", path.display())),
        }
    }

    /// Writes the list to `path` in one step (a temporary file renamed over
    /// it), so a server reading it never sees half a file.
    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        let text = format!(
            "# Revoked certificates and identities (docs/security.md); servers read this\n\
             # file again within a second of a change.\n{}",
            toml::to_string(self)?
        );
        let tmp = path.with_extension("toml.tmp");
        std::fs::write(&tmp, text).with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::rename(&tmp, path).with_context(|| format!("cannot replace {}", path.display()))
    }

    /// Adds `entry` unless an entry for the same identity and serial is
    /// there already; returns whether it was added.
    pub fn add(&mut self, entry: Revoked) -> bool {
        if self.entries.iter().any(|e| e.identity == entry.identity && e.serial == entry.serial) {
            return false;
        }
        self.entries.push(entry);
        true
    }

    /// Why `cert` is revoked, or `None` when it is not.
    pub fn revokes(&self, cert: &CertificateId) -> Option<String> {
        let hit = self.entries.iter().find(|e| {
            e.serial.as_deref().is_some_and(|s| s == cert.serial)
                || e.identity.as_deref().is_some_and(|id| cert.identities.iter().any(|c| c == id))
        })?;
        let what = match (&hit.identity, &hit.serial) {
            (Some(id), _) if cert.identities.contains(id) => format!("identity {id} is revoked"),
            _ => "certificate is revoked".to_string(),
        };
        let why = if hit.reason.is_empty() { String::new() } else { format!(" ({})", hit.reason) };
        Some(format!("{cert}: {what}{why}"))
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// The current list, replaced whenever the file changes.
pub type RevocationWatch = watch::Receiver<Arc<RevocationList>>;

/// The leaf certificate of a request's TLS connection, if it presented one.
fn peer_certificate(extensions: &http::Extensions) -> Option<CertificateId> {
    let certs = extensions.get::<TlsConnectInfo<TcpConnectInfo>>()?.peer_certs()?;
    certs.first().map(|leaf| CertificateId::of(leaf.as_ref()))
}

/// The status a revoked caller's call gets, and ends with.
fn revoked_status(why: &str) -> Status {
    Status::permission_denied(format!("{why}; this server no longer answers it"))
}

/// Refuses calls over a connection whose client certificate was revoked
/// after the handshake, and ends a call that runs when its caller's
/// certificate is revoked (a robot's Attach stream) with PERMISSION_DENIED
/// naming the revocation, in the response's trailers. Without a list
/// (plaintext) it passes every call through.
#[derive(Clone, Debug)]
pub struct RevocationLayer {
    list: Option<RevocationWatch>,
}

impl RevocationLayer {
    pub fn new(list: Option<RevocationWatch>) -> Self {
        Self { list }
    }
}

impl<S> tower::Layer<S> for RevocationLayer {
    type Service = Revocation<S>;
    fn layer(&self, inner: S) -> Revocation<S> {
        Revocation { inner, list: self.list.clone() }
    }
}

/// A service behind [`RevocationLayer`].
#[derive(Clone, Debug)]
pub struct Revocation<S> {
    inner: S,
    list: Option<RevocationWatch>,
}

impl<S, B> tower::Service<http::Request<B>> for Revocation<S>
where
    S: tower::Service<http::Request<B>, Response = http::Response<Body>>,
    S::Future: Send + 'static,
    S::Error: Send + 'static,
{
    type Response = http::Response<Body>;
    type Error = S::Error;
    type Future = BoxFuture<'static, Result<Self::Response, Self::Error>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        let (Some(list), Some(cert)) = (self.list.clone(), peer_certificate(req.extensions())) else {
            return Box::pin(self.inner.call(req));
        };
        let method = req.uri().path().to_string();
        if let Some(why) = list.borrow().revokes(&cert) {
            tracing::warn!(caller = %cert, method = %method, "refused: {why}");
            let status = revoked_status(&why);
            return Box::pin(futures::future::ready(Ok(status.into_http())));
        }
        let call = self.inner.call(req);
        Box::pin(async move {
            let response = call.await?;
            Ok(response.map(|body| Body::new(Revocable::new(body, revoked(list, cert, method)))))
        })
    }
}

/// Completes with why `cert` is revoked once the list says so.
fn revoked(mut list: RevocationWatch, cert: CertificateId, method: String) -> BoxFuture<'static, String> {
    Box::pin(async move {
        loop {
            if let Some(why) = list.borrow_and_update().revokes(&cert) {
                tracing::warn!(caller = %cert, method = %method, "ending the call: {why}");
                return why;
            }
            if list.changed().await.is_err() {
                // The server is shutting down; its own drain ends the call.
                return std::future::pending().await;
            }
        }
    })
}

/// `grpc-status` and `grpc-message` of `status`, as trailers.
fn status_trailers(status: Status) -> http::HeaderMap {
    let headers = status.into_http::<Body>().into_parts().0.headers;
    let mut trailers = http::HeaderMap::new();
    for name in ["grpc-status", "grpc-message"] {
        if let Some(v) = headers.get(name) {
            trailers.insert(name, v.clone());
        }
    }
    trailers
}

/// A response body that ends with PERMISSION_DENIED once `revoked` completes.
struct Revocable {
    inner: Body,
    revoked: BoxFuture<'static, String>,
    done: bool,
}

impl Revocable {
    fn new(inner: Body, revoked: BoxFuture<'static, String>) -> Self {
        Self { inner, revoked, done: false }
    }
}

impl http_body::Body for Revocable {
    type Data = Bytes;
    type Error = Status;

    fn poll_frame(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Result<Frame<Bytes>, Status>>> {
        if self.done {
            return Poll::Ready(None);
        }
        if let Poll::Ready(why) = self.revoked.as_mut().poll(cx) {
            self.done = true;
            return Poll::Ready(Some(Ok(Frame::trailers(status_trailers(revoked_status(&why))))));
        }
        let polled = Pin::new(&mut self.inner).poll_frame(cx);
        if let Poll::Ready(None) = polled {
            self.done = true;
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.done || self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serials_compare_in_any_spelling() {
        assert_eq!(normalize_serial("0A:1b:FF"), Some("0a1bff".into()));
        assert_eq!(normalize_serial("00a1"), Some("a1".into()));
        assert_eq!(normalize_serial("abc"), Some("0abc".into()));
        assert_eq!(normalize_serial("0x00"), Some("00".into()));
        for bad in ["", ":", "xyz", "12 34", "-1"] {
            assert_eq!(normalize_serial(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn an_identity_revokes_every_certificate_naming_it_and_a_serial_one_certificate() {
        let list = RevocationList::parse(
            "[[revoked]]\nidentity = \"spiffe://vlnav/robot/husky-1\"\nreason = \"lost\"\n\
             [[revoked]]\nserial = \"0A:BC\"\n",
        )
        .unwrap();
        let husky1 = CertificateId { serial: "01".into(), identities: vec!["spiffe://vlnav/robot/husky-1".into()] };
        let why = list.revokes(&husky1).unwrap();
        assert_eq!(
            why,
            "the certificate of spiffe://vlnav/robot/husky-1 (serial 01): identity spiffe://vlnav/robot/husky-1 \
             is revoked (lost)"
        );
        let husky2 = CertificateId { serial: "0abc".into(), identities: vec!["spiffe://vlnav/robot/husky-2".into()] };
        assert!(list.revokes(&husky2).unwrap().ends_with("(serial 0abc): certificate is revoked"));
        let other = CertificateId { serial: "0abd".into(), identities: vec!["spiffe://vlnav/robot/husky-11".into()] };
        assert_eq!(list.revokes(&other), None);
    }

    #[test]
    fn lists_that_say_nothing_clear_are_refused_with_the_entry_named() {
        for (text, says) in [
            ("[[revoked]]\nreason = \"x\"\n", "entry 1 names neither"),
            ("[[revoked]]\nidentity = \"husky-1\"\n", "not a spiffe:// URI"),
            ("[[revoked]]\nidentity = \"spiffe://\"\n", "not a spiffe:// URI"),
            ("[[revoked]]\nserial = \"zz\"\n", "serial \"zz\" is not hex"),
            ("[[revoked]]\nidentity = \"spiffe://vlnav/robot/a\"\nserail = \"01\"\n", "not a revocation list"),
            ("revoked = 3", "not a revocation list"),
        ] {
            let e = format!("{:#}", RevocationList::parse(text).unwrap_err());
            assert!(e.contains(says), "{text:?}: {e}");
        }
        assert!(RevocationList::parse("").unwrap().is_empty());
    }

    #[test]
    fn a_saved_list_loads_back_and_a_missing_file_is_empty() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("revoked.toml");
        assert!(RevocationList::load(&path).unwrap().is_empty());
        let mut list = RevocationList::default();
        let entry = Revoked { identity: Some("spiffe://vlnav/service/planner".into()), ..Default::default() };
        assert!(list.add(entry.clone()));
        assert!(!list.add(entry), "the same entry twice");
        assert!(list.add(Revoked { serial: Some("0abc".into()), reason: "key leaked".into(), ..Default::default() }));
        list.save(&path).unwrap();
        assert_eq!(RevocationList::load(&path).unwrap(), list);
        assert!(!dir.path().join("revoked.toml.tmp").exists());
    }

    #[test]
    fn a_dev_certificate_is_known_by_its_serial_and_identity() {
        let dir = tempfile::tempdir().unwrap();
        let pki = crate::security::DevPki::ensure(dir.path(), &["husky-1"]).unwrap();
        let id = CertificateId::of_pem_file(&pki.robot_cert("husky-1")).unwrap();
        assert_eq!(id.identities, vec!["spiffe://vlnav/robot/husky-1".to_string()]);
        assert!(id.serial.len() >= 2 && normalize_serial(&id.serial) == Some(id.serial.clone()), "{id:?}");
        let gateway = CertificateId::of_pem_file(&pki.gateway_cert()).unwrap();
        assert_ne!(gateway.serial, id.serial);
        assert!(CertificateId::of_pem_file(&pki.robot_key("husky-1")).is_err(), "a key is no certificate");
        assert!(CertificateId::of_pem_file(&dir.path().join("none.pem")).is_err());
    }
}
