//! The rustls side of every server and client (docs/security.md): a
//! server's certificate and key, and the revocation list, read again when
//! their files change, so cert-manager renewals and revocations take effect
//! without a restart; the client certificate a channel presents, read again
//! at each new connection when its files changed.
//!
//! - A server's certificate is served by a resolver whose [`CertifiedKey`]
//!   is swapped when the files change: the next handshake presents the new
//!   certificate, connections already open keep theirs.
//! - Callers' certificates are verified against the client CA (webpki), then
//!   against the revocation list ([`crate::revocation`]); a revoked one is
//!   refused with the TLS alert `certificate_revoked`.
//! - Handshakes run off the accept loop, each within [`HANDSHAKE_TIMEOUT`].
//! - Both ends read their TCP socket through [`BufferedTcp`]: rustls asks
//!   its transport for 4 KiB at a time, so a 640×480 RGB-D frame (1.5 MB)
//!   would take some 370 reads from the socket, each a system call.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};
use std::time::Duration;

use anyhow::Context as _;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, watch};
use tokio_rustls::rustls;
use tokio_rustls::rustls::client::ResolvesClientCert;
use tokio_rustls::rustls::crypto::CryptoProvider;
use tokio_rustls::rustls::pki_types::pem::PemObject as _;
use tokio_rustls::rustls::pki_types::{CertificateDer, PrivateKeyDer, ServerName, UnixTime};
use tokio_rustls::rustls::server::danger::{ClientCertVerified, ClientCertVerifier};
use tokio_rustls::rustls::server::{ClientHello, ResolvesServerCert, WebPkiClientVerifier};
use tokio_rustls::rustls::sign::CertifiedKey;
use tokio_rustls::rustls::{DigitallySignedStruct, DistinguishedName, SignatureScheme};
use tokio_util::sync::CancellationToken;

use crate::revocation::{CertificateId, RevocationList, RevocationWatch};

/// How often a server looks at its certificate, key and revocation list.
pub const RELOAD_INTERVAL: Duration = Duration::from_secs(1);
/// A TLS handshake not done within this is dropped.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

fn provider() -> Arc<CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

fn certificates(pem: &[u8], path: &Path) -> anyhow::Result<Vec<CertificateDer<'static>>> {
    let certs = CertificateDer::pem_slice_iter(pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("{}: not a PEM certificate chain ({e})", path.display()))?;
    if certs.is_empty() {
        anyhow::bail!("{} holds no certificate", path.display());
    }
    Ok(certs)
}

/// A certificate chain and its key, both files read.
fn certified_key(cert: &Path, key: &Path) -> anyhow::Result<(CertifiedKey, Vec<u8>)> {
    let cert_pem = std::fs::read(cert).with_context(|| format!("cannot read {}", cert.display()))?;
    let key_pem = std::fs::read(key).with_context(|| format!("cannot read {}", key.display()))?;
    let certified = certified_key_of(&cert_pem, &key_pem, cert, key)?;
    let mut both = cert_pem;
    both.extend_from_slice(&key_pem);
    Ok((certified, both))
}

fn certified_key_of(cert_pem: &[u8], key_pem: &[u8], cert: &Path, key: &Path) -> anyhow::Result<CertifiedKey> {
    let chain = certificates(cert_pem, cert)?;
    let key_der = PrivateKeyDer::from_pem_slice(key_pem)
        .map_err(|e| anyhow::anyhow!("{}: not a PEM private key ({e})", key.display()))?;
    let signing = provider()
        .key_provider
        .load_private_key(key_der)
        .map_err(|e| anyhow::anyhow!("{}: unusable private key ({e})", key.display()))?;
    let certified = CertifiedKey::new(chain, signing);
    certified
        .keys_match()
        .map_err(|e| anyhow::anyhow!("{} is not the key of {} ({e})", key.display(), cert.display()))?;
    Ok(certified)
}

/// The serial of a chain's leaf, for logs.
fn leaf_serial(key: &CertifiedKey) -> String {
    key.cert.first().map(|c| CertificateId::of(c.as_ref()).serial).unwrap_or_default()
}

/// A certificate and key read from files, replaced when the files change
/// (or given as bytes, then fixed).
#[derive(Debug)]
pub struct CertificateFiles {
    cert: PathBuf,
    key: PathBuf,
    fixed: bool,
    current: RwLock<Arc<CertifiedKey>>,
    /// The files' bytes when last read (certificate, then key), loaded or
    /// not: a pair is tried, and a failure logged, once per change.
    seen: Mutex<Vec<u8>>,
}

impl CertificateFiles {
    /// Reads both files; an error names the file at fault.
    pub fn load(cert: &Path, key: &Path) -> anyhow::Result<Self> {
        let (certified, read) = certified_key(cert, key)?;
        Ok(Self {
            cert: cert.to_path_buf(),
            key: key.to_path_buf(),
            fixed: false,
            current: RwLock::new(Arc::new(certified)),
            seen: Mutex::new(read),
        })
    }

    /// A certificate and key given as PEM bytes: never read again.
    pub fn fixed(cert_pem: &[u8], key_pem: &[u8]) -> anyhow::Result<Self> {
        let (cert, key) = (Path::new("the client certificate"), Path::new("the client key"));
        let certified = certified_key_of(cert_pem, key_pem, cert, key)?;
        Ok(Self {
            cert: cert.to_path_buf(),
            key: key.to_path_buf(),
            fixed: true,
            current: RwLock::new(Arc::new(certified)),
            seen: Mutex::new(Vec::new()),
        })
    }

    /// The certificate and key in use.
    pub fn current(&self) -> Arc<CertifiedKey> {
        self.current.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Reads the files again and swaps in what they hold if it changed and
    /// is a usable pair; returns whether it swapped. A pair that does not
    /// load (a renewal half written: a new certificate, the old key) is
    /// logged and the previous one stays.
    pub fn refresh(&self) -> bool {
        if self.fixed {
            return false;
        }
        let mut seen = self.seen.lock().unwrap_or_else(|e| e.into_inner());
        let (cert, key) = match (std::fs::read(&self.cert), std::fs::read(&self.key)) {
            (Ok(c), Ok(k)) => (c, k),
            (Err(e), _) | (_, Err(e)) => {
                if !seen.is_empty() {
                    tracing::warn!(cert = %self.cert.display(), key = %self.key.display(), "cannot read the certificate or its key ({e}); keeping the one in use");
                    seen.clear();
                }
                return false;
            }
        };
        let mut both = cert.clone();
        both.extend_from_slice(&key);
        if *seen == both {
            return false;
        }
        *seen = both;
        match certified_key_of(&cert, &key, &self.cert, &self.key) {
            Ok(certified) => {
                let serial = leaf_serial(&certified);
                *self.current.write().unwrap_or_else(|e| e.into_inner()) = Arc::new(certified);
                tracing::info!(cert = %self.cert.display(), %serial, "certificate renewed: new handshakes present it");
                true
            }
            Err(e) => {
                tracing::warn!(cert = %self.cert.display(), "{e:#}; keeping the certificate in use");
                false
            }
        }
    }
}

/// Serves the current certificate of a [`CertificateFiles`].
#[derive(Debug)]
struct Resolver(Arc<CertificateFiles>);

impl ResolvesServerCert for Resolver {
    fn resolve(&self, _: ClientHello<'_>) -> Option<Arc<CertifiedKey>> {
        Some(self.0.current())
    }
}

impl ResolvesClientCert for Resolver {
    fn resolve(&self, _: &[&[u8]], _: &[SignatureScheme]) -> Option<Arc<CertifiedKey>> {
        Some(self.0.current())
    }

    fn has_certs(&self) -> bool {
        true
    }
}

/// webpki's verification of a caller's certificate, then the revocation list.
#[derive(Debug)]
struct RevokingVerifier {
    webpki: Arc<dyn ClientCertVerifier>,
    revoked: RevocationWatch,
}

impl ClientCertVerifier for RevokingVerifier {
    fn offer_client_auth(&self) -> bool {
        self.webpki.offer_client_auth()
    }

    fn client_auth_mandatory(&self) -> bool {
        self.webpki.client_auth_mandatory()
    }

    fn root_hint_subjects(&self) -> &[DistinguishedName] {
        self.webpki.root_hint_subjects()
    }

    fn verify_client_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        intermediates: &[CertificateDer<'_>],
        now: UnixTime,
    ) -> Result<ClientCertVerified, rustls::Error> {
        let verified = self.webpki.verify_client_cert(end_entity, intermediates, now)?;
        let cert = CertificateId::of(end_entity.as_ref());
        if let Some(why) = self.revoked.borrow().revokes(&cert) {
            tracing::warn!(caller = %cert, "TLS handshake refused: {why}");
            return Err(rustls::Error::InvalidCertificate(rustls::CertificateError::Revoked));
        }
        Ok(verified)
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<rustls::client::danger::HandshakeSignatureValid, rustls::Error> {
        self.webpki.verify_tls12_signature(message, cert, dss)
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<rustls::client::danger::HandshakeSignatureValid, rustls::Error> {
        self.webpki.verify_tls13_signature(message, cert, dss)
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.webpki.supported_verify_schemes()
    }
}

/// The revocation list of a file, watched.
#[derive(Debug)]
struct RevocationFile {
    path: PathBuf,
    read: Option<Vec<u8>>,
    tx: watch::Sender<Arc<RevocationList>>,
}

impl RevocationFile {
    fn open(path: &Path) -> anyhow::Result<(Self, RevocationWatch)> {
        let read = match std::fs::read(path) {
            Ok(bytes) => Some(bytes),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e) => return Err(e).with_context(|| format!("cannot read the revocation list {}", path.display())),
        };
        let list = match &read {
            Some(bytes) => RevocationList::parse(&String::from_utf8_lossy(bytes))
                .with_context(|| format!("the revocation list {}", path.display()))?,
            None => RevocationList::default(),
        };
        let (tx, rx) = watch::channel(Arc::new(list));
        Ok((Self { path: path.to_path_buf(), read, tx }, rx))
    }

    /// Reads the file again; a changed list that parses replaces the
    /// current one. A list that does not parse, or a file that vanished,
    /// is logged and the previous list stays (write an empty file to revoke
    /// nothing).
    fn refresh(&mut self) {
        let bytes = match std::fs::read(&self.path) {
            Ok(b) => b,
            Err(e) => {
                if self.read.is_some() {
                    tracing::warn!(path = %self.path.display(), "cannot read the revocation list ({e}); keeping the previous one");
                    self.read = None;
                }
                return;
            }
        };
        if self.read.as_ref() == Some(&bytes) {
            return;
        }
        match RevocationList::parse(&String::from_utf8_lossy(&bytes)) {
            Ok(list) => {
                tracing::info!(path = %self.path.display(), entries = list.entries.len(), "revocation list read");
                self.tx.send_replace(Arc::new(list));
            }
            Err(e) => {
                tracing::error!(path = %self.path.display(), "{e:#}; keeping the previous revocation list")
            }
        }
        self.read = Some(bytes);
    }
}

/// A server's TLS: its rustls settings and what they read from files.
#[derive(Debug)]
pub struct ServerTls {
    config: Arc<rustls::ServerConfig>,
    certificate: Arc<CertificateFiles>,
    revocation: Option<RevocationFile>,
    revoked: Option<RevocationWatch>,
}

impl ServerTls {
    /// Reads the certificate, key, client CA (mutual TLS when given) and
    /// revocation list. `client_optional`: callers without a certificate
    /// pass the handshake.
    pub fn load(
        cert: &Path,
        key: &Path,
        client_ca: Option<&Path>,
        revoked: Option<&Path>,
        client_optional: bool,
    ) -> anyhow::Result<Self> {
        let certificate = Arc::new(CertificateFiles::load(cert, key)?);
        let (revocation, watch) = match revoked {
            Some(p) => {
                let (file, rx) = RevocationFile::open(p)?;
                (Some(file), Some(rx))
            }
            None => (None, None),
        };
        let builder = rustls::ServerConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()
            .context("TLS protocol versions")?;
        let builder = match client_ca {
            Some(ca) => {
                let pem = std::fs::read(ca).with_context(|| format!("cannot read {}", ca.display()))?;
                let mut roots = rustls::RootCertStore::empty();
                for c in certificates(&pem, ca)? {
                    roots.add(c).with_context(|| format!("{}: not a usable CA certificate", ca.display()))?;
                }
                let mut webpki = WebPkiClientVerifier::builder_with_provider(Arc::new(roots), provider());
                if client_optional {
                    webpki = webpki.allow_unauthenticated();
                }
                let webpki = webpki.build().with_context(|| format!("client CA {}", ca.display()))?;
                let list = watch.clone().unwrap_or_else(|| watch::channel(Arc::new(RevocationList::default())).1);
                builder.with_client_cert_verifier(Arc::new(RevokingVerifier { webpki, revoked: list }))
            }
            None => builder.with_no_client_auth(),
        };
        let mut config = builder.with_cert_resolver(Arc::new(Resolver(certificate.clone())));
        config.alpn_protocols = vec![b"h2".to_vec()];
        Ok(Self { config: Arc::new(config), certificate, revocation, revoked: watch })
    }

    /// The revocation list in force, when the server has one.
    pub fn revoked(&self) -> Option<RevocationWatch> {
        self.revoked.clone()
    }

    /// Accepts connections on `listener` and yields those whose TLS
    /// handshake succeeded, until `shutdown`; meanwhile looks at the
    /// certificate, key and revocation list every [`RELOAD_INTERVAL`].
    pub fn incoming(
        self,
        listener: TcpListener,
        shutdown: CancellationToken,
    ) -> impl futures::Stream<Item = std::io::Result<ServerStream>> + Send + 'static {
        let Self { config, certificate, mut revocation, .. } = self;
        let acceptor = tokio_rustls::TlsAcceptor::from(config);
        let (tx, rx) = mpsc::channel(64);
        let stop = shutdown.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(RELOAD_INTERVAL);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                tokio::select! {
                    _ = stop.cancelled() => return,
                    _ = tick.tick() => {
                        certificate.refresh();
                        if let Some(r) = revocation.as_mut() {
                            r.refresh();
                        }
                    }
                }
            }
        });
        tokio::spawn(async move {
            loop {
                let accepted = tokio::select! {
                    _ = shutdown.cancelled() => return,
                    _ = tx.closed() => return,
                    a = listener.accept() => a,
                };
                let (tcp, peer) = match accepted {
                    Ok(a) => a,
                    Err(e) => {
                        // Out of file descriptors and the like: wait, then go on.
                        tracing::warn!("accepting a connection failed: {e}");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                };
                // Nagle would hold a response's last segment until the
                // client's delayed ACK (~40 ms).
                let _ = tcp.set_nodelay(true);
                let (acceptor, tx) = (acceptor.clone(), tx.clone());
                tokio::spawn(async move {
                    match tokio::time::timeout(HANDSHAKE_TIMEOUT, acceptor.accept(BufferedTcp::new(tcp))).await {
                        Ok(Ok(tls)) => {
                            let _ = tx.send(Ok(tls)).await;
                        }
                        Ok(Err(e)) => tracing::debug!(%peer, "TLS handshake failed: {e}"),
                        Err(_) => tracing::debug!(%peer, "TLS handshake timed out"),
                    }
                });
            }
        });
        tokio_stream::wrappers::ReceiverStream::new(rx)
    }
}

/// A client's TLS over rustls: the CA servers are verified against, and a
/// client certificate read again from its files before each new connection
/// when they changed (renewal without a restart).
#[derive(Clone, Debug)]
pub struct ClientConnector {
    config: Arc<rustls::ClientConfig>,
    certificate: Option<Arc<CertificateFiles>>,
    domain: Option<String>,
}

impl ClientConnector {
    /// `ca_pem`: the CA servers must be signed by; `identity`: the client
    /// certificate and key; `domain`: the name the server's certificate must carry
    /// when it is not the address's host.
    pub fn new(ca_pem: &[u8], identity: Option<CertificateFiles>, domain: Option<&str>) -> anyhow::Result<Self> {
        let mut roots = rustls::RootCertStore::empty();
        for c in certificates(ca_pem, Path::new("the CA"))? {
            roots.add(c).context("not a usable CA certificate")?;
        }
        let builder = rustls::ClientConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()
            .context("TLS protocol versions")?
            .with_root_certificates(roots);
        let certificate = identity.map(Arc::new);
        let mut config = match &certificate {
            Some(files) => builder.with_client_cert_resolver(Arc::new(Resolver(files.clone()))),
            None => builder.with_no_client_auth(),
        };
        config.alpn_protocols = vec![b"h2".to_vec()];
        Ok(Self { config: Arc::new(config), certificate, domain: domain.map(str::to_string) })
    }

    /// The client certificate that the next connection presents.
    pub fn certificate(&self) -> Option<Arc<CertifiedKey>> {
        self.certificate.as_ref().map(|c| c.current())
    }

    /// A TCP connection to `host:port`, then TLS verified for `domain` (or
    /// `host`), presenting the client certificate as its files are now.
    pub async fn connect(&self, host: &str, port: u16) -> std::io::Result<ClientStream> {
        if let Some(files) = &self.certificate {
            files.refresh();
        }
        let host = host.trim_start_matches('[').trim_end_matches(']');
        let name = ServerName::try_from(self.domain.as_deref().unwrap_or(host).to_string())
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        let tcp = TcpStream::connect((host, port)).await?;
        tcp.set_nodelay(true)?;
        tokio_rustls::TlsConnector::from(self.config.clone()).connect(name, BufferedTcp::new(tcp)).await
    }
}

impl tower::Service<http::Uri> for ClientConnector {
    type Response = hyper_util::rt::TokioIo<ClientStream>;
    type Error = std::io::Error;
    type Future = futures::future::BoxFuture<'static, std::io::Result<Self::Response>>;

    fn poll_ready(&mut self, _: &mut std::task::Context<'_>) -> std::task::Poll<std::io::Result<()>> {
        std::task::Poll::Ready(Ok(()))
    }

    fn call(&mut self, uri: http::Uri) -> Self::Future {
        let this = self.clone();
        Box::pin(async move {
            let host = uri
                .host()
                .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("{uri} names no host")))?;
            let port = uri.port_u16().unwrap_or(443);
            this.connect(host, port).await.map(hyper_util::rt::TokioIo::new)
        })
    }
}

/// A server's end of an accepted connection, after its TLS handshake.
pub type ServerStream = tokio_rustls::server::TlsStream<BufferedTcp>;
/// A client's end of a connection, after its TLS handshake.
pub type ClientStream = tokio_rustls::client::TlsStream<BufferedTcp>;

/// Bytes [`BufferedTcp`] reads from its socket at a time, at most.
pub const READ_BUFFER: usize = 256 * 1024;

/// A TCP connection read up to [`READ_BUFFER`] bytes at a time, written
/// straight through. rustls reads its transport 4 KiB at a time (its
/// deframer's read size); below it, this turns a megabyte frame's hundreds
/// of socket reads into a few and hands rustls its 4 KiB from memory.
/// `cargo bench -p vlnav-runtime --bench hop` measures a hop with it.
#[derive(Debug)]
pub struct BufferedTcp(tokio::io::BufReader<TcpStream>);

impl BufferedTcp {
    pub fn new(tcp: TcpStream) -> Self {
        Self(tokio::io::BufReader::with_capacity(READ_BUFFER, tcp))
    }

    /// The socket.
    pub fn get_ref(&self) -> &TcpStream {
        self.0.get_ref()
    }
}

impl tokio::io::AsyncRead for BufferedTcp {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_read(cx, buf)
    }
}

impl tokio::io::AsyncWrite for BufferedTcp {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.0).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.0).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.0.is_write_vectored()
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_shutdown(cx)
    }
}

/// The peer's address, as tonic gives a plain socket's to its handlers
/// (and, under TLS, beside the peer's certificates: crate::authz).
impl tonic::transport::server::Connected for BufferedTcp {
    type ConnectInfo = tonic::transport::server::TcpConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        <TcpStream as tonic::transport::server::Connected>::connect_info(self.get_ref())
    }
}
