//! Transport security every vlnav server and client shares (docs/security.md):
//! TLS settings of servers and clients, the identities certificates carry
//! (`spiffe://vlnav/robot/<id>`, `spiffe://vlnav/service/<name>`), bearer
//! tokens and their hashes, and the development PKI `vlnav up` creates on
//! first start.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr};
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use sha2::Digest as _;
use tonic::transport::{Certificate, ClientTlsConfig, Identity};

/// URI SAN prefix of a robot's certificate; the rest is its `robot_id`.
pub const ROBOT_IDENTITY_PREFIX: &str = "spiffe://vlnav/robot/";
/// URI SAN prefix of a service's certificate; the rest is its name.
pub const SERVICE_IDENTITY_PREFIX: &str = "spiffe://vlnav/service/";
/// The gateway's identity: the only caller the stages answer
/// (`crate::authz::CallerPolicy::stages`).
pub const GATEWAY_IDENTITY: &str = "spiffe://vlnav/service/gateway";

/// The identity a robot's certificate must carry.
pub fn robot_identity(robot_id: &str) -> String {
    format!("{ROBOT_IDENTITY_PREFIX}{robot_id}")
}

/// The identity a service's certificate carries.
pub fn service_identity(name: &str) -> String {
    format!("{SERVICE_IDENTITY_PREFIX}{name}")
}

/// Whether `id` can be a robot id: 1–64 letters, digits, '-', '_' or '.'
/// (it names the robot in certificates, file names and metrics).
pub fn valid_robot_id(id: &str) -> bool {
    !id.is_empty() && id.len() <= 64 && id.chars().all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
}

fn check_robot_id(robot_id: &str) -> anyhow::Result<()> {
    if !valid_robot_id(robot_id) {
        anyhow::bail!("robot id {robot_id:?}: use 1–64 letters, digits, '-', '_' or '.' for a certificate identity");
    }
    Ok(())
}

/// TLS of a server. With a certificate and key the server speaks only TLS;
/// with a client CA as well it asks callers for a certificate that CA
/// signed (mutual TLS). The certificate, the key and the revocation list are
/// read again within a second of a change (docs/security.md).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ServerTlsArgs {
    /// PEM certificate chain this server presents (read again when it changes).
    #[arg(long, env = "VLNAV_TLS_CERT")]
    pub tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert.
    #[arg(long, env = "VLNAV_TLS_KEY")]
    pub tls_key: Option<PathBuf>,
    /// PEM CA a caller's certificate must be signed by (mutual TLS).
    #[arg(long, env = "VLNAV_TLS_CLIENT_CA")]
    pub tls_client_ca: Option<PathBuf>,
    /// Revoked identities and certificate serials (TOML, written by `vlnav
    /// credentials revoke`): refused at the handshake, and their running
    /// calls ended, within a second of a change. A missing file revokes
    /// nothing until it appears.
    #[arg(long, env = "VLNAV_TLS_REVOKED")]
    pub tls_revoked: Option<PathBuf>,
}

impl ServerTlsArgs {
    pub fn enabled(&self) -> bool {
        self.tls_cert.is_some() || self.tls_key.is_some()
    }

    /// The server's TLS, or `None` for plaintext. `client_optional`:
    /// callers without a certificate are let through to the next check (the
    /// gateway's token layer); otherwise the handshake refuses them.
    pub fn load(&self, client_optional: bool) -> anyhow::Result<Option<crate::tls::ServerTls>> {
        let (cert, key) = match (&self.tls_cert, &self.tls_key) {
            (None, None) if self.tls_client_ca.is_some() => {
                anyhow::bail!("--tls-client-ca needs --tls-cert and --tls-key: mutual TLS is TLS first")
            }
            (None, None) if self.tls_revoked.is_some() => {
                anyhow::bail!(
                    "--tls-revoked needs --tls-cert, --tls-key and --tls-client-ca: revocation is of client certificates"
                )
            }
            (None, None) => return Ok(None),
            (Some(c), Some(k)) => (c, k),
            _ => anyhow::bail!("give both --tls-cert and --tls-key (VLNAV_TLS_CERT, VLNAV_TLS_KEY), or neither"),
        };
        if self.tls_revoked.is_some() && self.tls_client_ca.is_none() {
            anyhow::bail!(
                "--tls-revoked needs --tls-client-ca (VLNAV_TLS_CLIENT_CA): without it no caller presents a certificate to revoke"
            );
        }
        crate::tls::ServerTls::load(
            cert,
            key,
            self.tls_client_ca.as_deref(),
            self.tls_revoked.as_deref(),
            client_optional,
        )
        .map(Some)
    }
}

/// TLS of a client: the CA servers are verified against, and the
/// certificate it presents for mutual TLS.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ClientTlsArgs {
    /// PEM CA that signed the servers' certificates; `https://` addresses
    /// are verified against it and nothing else.
    #[arg(long, env = "VLNAV_TLS_CA")]
    pub tls_ca: Option<PathBuf>,
    /// PEM certificate this client presents (mutual TLS).
    #[arg(long, env = "VLNAV_TLS_CLIENT_CERT")]
    pub tls_client_cert: Option<PathBuf>,
    /// PEM private key of --tls-client-cert.
    #[arg(long, env = "VLNAV_TLS_CLIENT_KEY")]
    pub tls_client_key: Option<PathBuf>,
}

impl ClientTlsArgs {
    /// The files, read; `None` when no CA is given (plaintext only).
    pub fn load(&self) -> anyhow::Result<Option<ClientTls>> {
        if self.tls_ca.is_none() && (self.tls_client_cert.is_some() || self.tls_client_key.is_some()) {
            anyhow::bail!(
                "--tls-client-cert needs --tls-ca (VLNAV_TLS_CA): a client verifies the server before it shows its certificate"
            );
        }
        let (identity, identity_files) = match (&self.tls_client_cert, &self.tls_client_key) {
            (None, None) => (None, None),
            (Some(c), Some(k)) => (Some((read_pem(c)?, read_pem(k)?)), Some((c.clone(), k.clone()))),
            _ => anyhow::bail!(
                "give both --tls-client-cert and --tls-client-key (VLNAV_TLS_CLIENT_CERT, VLNAV_TLS_CLIENT_KEY), or neither"
            ),
        };
        match &self.tls_ca {
            Some(ca) => Ok(Some(ClientTls { ca_pem: read_pem(ca)?, identity, identity_files })),
            None => Ok(None),
        }
    }
}

/// A client's TLS material, read; with the files of its certificate when
/// it came from files, which are read again at each new connection when
/// they changed (renewal without a restart).
#[derive(Clone, Debug)]
pub struct ClientTls {
    ca_pem: Vec<u8>,
    identity: Option<(Vec<u8>, Vec<u8>)>,
    identity_files: Option<(PathBuf, PathBuf)>,
}

impl ClientTls {
    pub fn new(ca_pem: Vec<u8>, identity: Option<(Vec<u8>, Vec<u8>)>) -> Self {
        Self { ca_pem, identity, identity_files: None }
    }

    /// Presenting the certificate and key in these files, read now and again
    /// at each new connection when they changed.
    pub fn from_files(ca_pem: Vec<u8>, cert: &Path, key: &Path) -> anyhow::Result<Self> {
        let identity = Some((read_pem(cert)?, read_pem(key)?));
        Ok(Self { ca_pem, identity, identity_files: Some((cert.to_path_buf(), key.to_path_buf())) })
    }

    /// The rustls connector of a channel to one address: verifies servers
    /// against the CA (for `domain` when given, else the address's host) and
    /// presents the client certificate as its files are at each connection.
    pub fn connector(&self, domain: Option<&str>) -> anyhow::Result<crate::tls::ClientConnector> {
        let identity = match (&self.identity_files, &self.identity) {
            (Some((c, k)), _) => Some(crate::tls::CertificateFiles::load(c, k)?),
            (None, Some((c, k))) => Some(crate::tls::CertificateFiles::fixed(c, k)?),
            (None, None) => None,
        };
        crate::tls::ClientConnector::new(&self.ca_pem, identity, domain)
    }

    /// tonic's settings: only the given CA is trusted (no system roots);
    /// `domain` overrides the name the server's certificate must carry. A
    /// certificate from files is read from them now.
    pub fn config(&self, domain: Option<&str>) -> ClientTlsConfig {
        let mut cfg = ClientTlsConfig::new().ca_certificate(Certificate::from_pem(&self.ca_pem));
        let current = self.identity_files.as_ref().and_then(|(c, k)| Some((read_pem(c).ok()?, read_pem(k).ok()?)));
        if let Some((cert, key)) = current.as_ref().or(self.identity.as_ref()) {
            cfg = cfg.identity(Identity::from_pem(cert, key));
        }
        if let Some(d) = domain {
            cfg = cfg.domain_name(d);
        }
        cfg
    }
}

/// What a client brings: TLS (for `https://` addresses) and a bearer token.
#[derive(Clone, Debug, Default)]
pub struct ClientSecurity {
    pub tls: Option<ClientTls>,
    pub bearer: Option<String>,
}

impl ClientSecurity {
    pub fn new(tls: Option<ClientTls>, bearer: Option<String>) -> Self {
        Self { tls, bearer }
    }

    /// Nothing: plaintext, no token.
    pub fn none() -> Self {
        Self::default()
    }
}

/// How a command-line client (`vlnav mission`, `vlnav profile`) calls the
/// gateway: the CA to verify it and a bearer token, by default those `vlnav
/// up` wrote to `.vlnav/security`.
#[derive(clap::Args, Clone, Debug)]
pub struct CallerArgs {
    /// PEM CA of the gateway's certificate (for https://); default
    /// <credentials-dir>/ca.pem when it exists.
    #[arg(long, env = "VLNAV_CA")]
    pub ca: Option<PathBuf>,
    /// File holding the bearer token; default <credentials-dir>/operator.token when it exists.
    #[arg(long, env = "VLNAV_TOKEN_FILE")]
    pub token_file: Option<PathBuf>,
    /// Where `vlnav up` wrote its development credentials.
    #[arg(long, env = "VLNAV_CREDENTIALS_DIR", default_value = ".vlnav/security")]
    pub credentials_dir: PathBuf,
}

impl Default for CallerArgs {
    fn default() -> Self {
        Self { ca: None, token_file: None, credentials_dir: PathBuf::from(".vlnav/security") }
    }
}

impl CallerArgs {
    /// The CA and token, read. A file named explicitly must exist; the
    /// defaults are used only when present.
    pub fn load(&self) -> anyhow::Result<ClientSecurity> {
        let pick = |given: &Option<PathBuf>, default: &str| match given {
            Some(p) => Some(p.clone()),
            None => Some(self.credentials_dir.join(default)).filter(|p| p.exists()),
        };
        let tls = pick(&self.ca, "ca.pem").map(|ca| read_pem(&ca).map(|pem| ClientTls::new(pem, None))).transpose()?;
        let bearer = pick(&self.token_file, "operator.token").map(|f| read_token(&f)).transpose()?;
        Ok(ClientSecurity { tls, bearer })
    }
}

fn read_pem(path: &Path) -> anyhow::Result<Vec<u8>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    if !bytes.windows(11).any(|w| w == b"-----BEGIN ") {
        anyhow::bail!("{} is not PEM (no -----BEGIN line)", path.display());
    }
    Ok(bytes)
}

/// Reads a token file: its first non-empty line, trimmed.
pub fn read_token(path: &Path) -> anyhow::Result<String> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read the token file {}", path.display()))?;
    text.lines()
        .map(str::trim)
        .find(|l| !l.is_empty())
        .map(str::to_string)
        .ok_or_else(|| anyhow::anyhow!("the token file {} is empty", path.display()))
}

/// SHA-256 of a bearer token, lower-case hex: what token files store.
pub fn token_hash(token: &str) -> String {
    hex(&sha2::Sha256::digest(token.as_bytes()))
}

/// A new random bearer token (256 bits, hex).
pub fn new_token() -> String {
    hex(&rand::random::<[u8; 32]>())
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The subject-alternative names of a DER certificate that `pick` keeps;
/// empty when it cannot be parsed or has none.
fn sans<T>(der: &[u8], pick: impl Fn(&x509_parser::extensions::GeneralName) -> Option<T>) -> Vec<T> {
    let Ok((_, cert)) = x509_parser::parse_x509_certificate(der) else {
        return Vec::new();
    };
    let Ok(Some(san)) = cert.subject_alternative_name() else {
        return Vec::new();
    };
    san.value.general_names.iter().filter_map(pick).collect()
}

/// The URI subject-alternative names of a DER certificate (its SPIFFE-style
/// identities).
pub fn uri_sans(der: &[u8]) -> Vec<String> {
    use x509_parser::extensions::GeneralName;
    sans(der, |n| match n {
        GeneralName::URI(u) => Some(u.to_string()),
        _ => None,
    })
}

/// The DNS names and IP addresses a DER certificate is valid for as a server.
pub fn server_names(der: &[u8]) -> Vec<String> {
    use x509_parser::extensions::GeneralName;
    sans(der, |n| match n {
        GeneralName::DNSName(d) => Some(d.to_string()),
        GeneralName::IPAddress(b) => match b.len() {
            4 => Some(IpAddr::from(<[u8; 4]>::try_from(*b).ok()?).to_string()),
            16 => Some(IpAddr::from(<[u8; 16]>::try_from(*b).ok()?).to_string()),
            _ => None,
        },
        _ => None,
    })
}

/// The first certificate of a PEM text, as DER.
pub fn pem_to_der(pem: &[u8]) -> Option<Vec<u8>> {
    x509_parser::pem::parse_x509_pem(pem).ok().map(|(_, p)| p.contents)
}

/// The robot ids a peer's certificate chain names (its leaf's
/// `spiffe://vlnav/robot/<id>` SANs).
pub fn robot_ids_of_peer(certs: &[impl AsRef<[u8]>]) -> Vec<String> {
    certs
        .first()
        .map(|leaf| {
            uri_sans(leaf.as_ref())
                .into_iter()
                .filter_map(|u| u.strip_prefix(ROBOT_IDENTITY_PREFIX).map(str::to_string))
                .collect()
        })
        .unwrap_or_default()
}

/// A development PKI in one directory: a CA, a server certificate valid for
/// loopback (and the names [`DevPki::ensure_named`] adds), the gateway's client
/// certificate and one certificate per robot. Made on first use, reused
/// after; keys are written owner-only.
#[derive(Clone, Debug)]
pub struct DevPki {
    pub dir: PathBuf,
}

/// DNS names the development server certificate carries (with 127.0.0.1
/// and ::1): it is for one machine (docs/security.md).
pub const DEV_SERVER_NAMES: &[&str] = &["localhost"];

/// The revocation list's file name, beside the CA.
pub const REVOCATION_FILE: &str = "revoked.toml";

/// How long development certificates are valid, days.
pub const DEV_CERT_DAYS: i64 = 365;

impl DevPki {
    /// Opens the PKI in `dir`, creating the CA, server and gateway
    /// certificates if absent, and a certificate for each of `robots` that
    /// has none yet.
    pub fn ensure(dir: &Path, robots: &[&str]) -> anyhow::Result<Self> {
        Self::ensure_named(dir, robots, &[])
    }

    /// As [`DevPki::ensure`], with a server certificate that also names
    /// `server_names` (DNS names or IP addresses a robot or client on the
    /// network dials the gateway by). A server certificate that lacks one
    /// of them, or any of the loopback names, is issued again from the same
    /// CA, naming the loopback names and `server_names`.
    pub fn ensure_named(dir: &Path, robots: &[&str], server_names: &[String]) -> anyhow::Result<Self> {
        for name in server_names {
            check_server_name(name)?;
        }
        let pki = Self::ensure_ca(dir)?;
        let mut wanted: Vec<String> = DEV_SERVER_NAMES.iter().map(|n| n.to_string()).collect();
        wanted.extend([Ipv4Addr::LOCALHOST.to_string(), Ipv6Addr::LOCALHOST.to_string()]);
        for name in server_names {
            if !wanted.iter().any(|w| same_server_name(w, name)) {
                wanted.push(name.clone());
            }
        }
        let held = pki.server_names();
        let missing: Vec<&String> = wanted.iter().filter(|w| !held.iter().any(|h| same_server_name(h, w))).collect();
        if !missing.is_empty() {
            if pki.server_cert().exists() {
                tracing::info!(
                    cert = %pki.server_cert().display(),
                    ?missing,
                    "the server certificate does not name every requested name: issuing it again from the same CA"
                );
            }
            let mut sans: Vec<rcgen::SanType> = wanted.iter().map(|n| server_san(n)).collect::<anyhow::Result<_>>()?;
            sans.push(rcgen::SanType::URI(service_identity("server").try_into()?));
            pki.issue("vlnav server", sans, &pki.server_cert(), &pki.server_key())?;
        }
        if !pki.gateway_cert().exists() {
            let sans = vec![rcgen::SanType::URI(GATEWAY_IDENTITY.try_into()?)];
            pki.issue("vlnav gateway", sans, &pki.gateway_cert(), &pki.gateway_key())?;
        }
        for robot in robots {
            pki.ensure_robot(robot)?;
        }
        Ok(pki)
    }

    /// The DNS names and IP addresses the server certificate is valid for;
    /// empty when there is none or it cannot be read.
    pub fn server_names(&self) -> Vec<String> {
        std::fs::read(self.server_cert())
            .ok()
            .and_then(|pem| pem_to_der(&pem))
            .map(|der| server_names(&der))
            .unwrap_or_default()
    }

    /// Opens an existing CA in `dir` to issue certificates from, creating
    /// nothing: `ca.pem` must be a CA certificate, valid now, and
    /// `ca-key.pem` its private key. The error names the file at fault.
    pub fn open_ca(dir: &Path) -> anyhow::Result<Self> {
        let pki = Self { dir: dir.to_path_buf() };
        let (ca, ca_key) = (pki.ca(), pki.ca_key());
        if !dir.is_dir() {
            anyhow::bail!("{} is not a directory", dir.display());
        }
        for f in [&ca, &ca_key] {
            if !f.exists() {
                anyhow::bail!("{} holds no CA: {} is missing", dir.display(), f.display());
            }
        }
        let pem = read_pem(&ca)?;
        let der = pem_to_der(&pem).with_context(|| format!("{} is not a PEM certificate", ca.display()))?;
        let (_, cert) = x509_parser::parse_x509_certificate(&der)
            .map_err(|e| anyhow::anyhow!("{} is not an X.509 certificate: {e}", ca.display()))?;
        if !cert.is_ca() {
            anyhow::bail!("{} is not a CA certificate (no CA basic constraint)", ca.display());
        }
        if !cert.validity().is_valid() {
            anyhow::bail!(
                "the CA {} is valid from {} to {}, not now: make a new CA (certificates it signed must then be issued again)",
                ca.display(),
                cert.validity().not_before,
                cert.validity().not_after
            );
        }
        let key_text = std::fs::read_to_string(&ca_key).with_context(|| format!("cannot read {}", ca_key.display()))?;
        let key = rcgen::KeyPair::from_pem(&key_text)
            .map_err(|e| anyhow::anyhow!("{} is not a private key: {e}", ca_key.display()))?;
        if cert.public_key().subject_public_key.data.as_ref() != key.public_key_raw() {
            anyhow::bail!(
                "{} is not the key of {}: the two files come from different CAs",
                ca_key.display(),
                ca.display()
            );
        }
        Ok(pki)
    }

    /// Opens the PKI in `dir` with only its CA, created if absent (a new CA
    /// removes the certificates the old one signed).
    pub fn ensure_ca(dir: &Path) -> anyhow::Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let pki = Self { dir: dir.to_path_buf() };
        if !pki.ca().exists() || !pki.ca_key().exists() {
            let key = rcgen::KeyPair::generate()?;
            let mut params = rcgen::CertificateParams::new(Vec::<String>::new())?;
            params.distinguished_name.push(rcgen::DnType::CommonName, "vlnav development CA");
            params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
            params.key_usages = vec![rcgen::KeyUsagePurpose::KeyCertSign, rcgen::KeyUsagePurpose::CrlSign];
            validity(&mut params);
            let cert = params.self_signed(&key)?;
            write_private(&pki.ca_key(), &key.serialize_pem())?;
            std::fs::write(pki.ca(), cert.pem())?;
            for stale in ["server.pem", "gateway-client.pem"] {
                let _ = std::fs::remove_file(dir.join(stale));
            }
            if let Ok(entries) = std::fs::read_dir(dir) {
                for e in entries.flatten() {
                    if e.file_name().to_string_lossy().starts_with("robot-") {
                        let _ = std::fs::remove_file(e.path());
                    }
                }
            }
        }
        Ok(pki)
    }

    /// Issues robot `robot_id`'s certificate unless it exists.
    pub fn ensure_robot(&self, robot_id: &str) -> anyhow::Result<()> {
        check_robot_id(robot_id)?;
        if !self.robot_cert(robot_id).exists() {
            self.issue_robot(robot_id, &self.robot_cert(robot_id), &self.robot_key(robot_id))?;
        }
        Ok(())
    }

    /// Issues a new certificate for robot `robot_id` (URI SAN
    /// `spiffe://vlnav/robot/<robot_id>`, valid as a client), written to
    /// `cert_path` / `key_path`; nothing else is written.
    pub fn issue_robot(&self, robot_id: &str, cert_path: &Path, key_path: &Path) -> anyhow::Result<()> {
        check_robot_id(robot_id)?;
        let sans = vec![rcgen::SanType::URI(robot_identity(robot_id).try_into()?)];
        self.issue(&format!("vlnav robot {robot_id}"), sans, cert_path, key_path)
    }

    /// Issues a certificate for service `component` (URI SAN
    /// `spiffe://vlnav/service/<component>`) valid as a server for
    /// `dns_names` and as a client, written to `cert_path` / `key_path`.
    pub fn issue_service(
        &self,
        component: &str,
        dns_names: &[String],
        cert_path: &Path,
        key_path: &Path,
    ) -> anyhow::Result<()> {
        let mut sans: Vec<rcgen::SanType> = dns_names
            .iter()
            .map(|n| server_san(n))
            .collect::<anyhow::Result<_>>()
            .with_context(|| format!("{component}: a name in {dns_names:?} is not a valid DNS name"))?;
        sans.push(rcgen::SanType::URI(service_identity(component).try_into()?));
        self.issue(&format!("vlnav {component}"), sans, cert_path, key_path)
    }

    fn issue(&self, name: &str, sans: Vec<rcgen::SanType>, cert_path: &Path, key_path: &Path) -> anyhow::Result<()> {
        let read = |p: PathBuf| std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()));
        let ca_key = rcgen::KeyPair::from_pem(&read(self.ca_key())?)
            .with_context(|| format!("{} is not a private key", self.ca_key().display()))?;
        let issuer = rcgen::Issuer::from_ca_cert_pem(&read(self.ca())?, ca_key)
            .with_context(|| format!("{} is not a CA certificate", self.ca().display()))?;
        let key = rcgen::KeyPair::generate()?;
        let mut params = rcgen::CertificateParams::new(Vec::<String>::new())?;
        params.distinguished_name.push(rcgen::DnType::CommonName, name);
        params.subject_alt_names = sans;
        params.key_usages = vec![rcgen::KeyUsagePurpose::DigitalSignature];
        params.extended_key_usages =
            vec![rcgen::ExtendedKeyUsagePurpose::ServerAuth, rcgen::ExtendedKeyUsagePurpose::ClientAuth];
        validity(&mut params);
        let cert = params.signed_by(&key, &issuer)?;
        write_private(key_path, &key.serialize_pem())?;
        std::fs::write(cert_path, cert.pem())?;
        Ok(())
    }

    pub fn ca(&self) -> PathBuf {
        self.dir.join("ca.pem")
    }
    pub fn ca_key(&self) -> PathBuf {
        self.dir.join("ca-key.pem")
    }
    pub fn server_cert(&self) -> PathBuf {
        self.dir.join("server.pem")
    }
    pub fn server_key(&self) -> PathBuf {
        self.dir.join("server-key.pem")
    }
    pub fn gateway_cert(&self) -> PathBuf {
        self.dir.join("gateway-client.pem")
    }
    pub fn gateway_key(&self) -> PathBuf {
        self.dir.join("gateway-client-key.pem")
    }
    pub fn robot_cert(&self, robot_id: &str) -> PathBuf {
        self.dir.join(format!("robot-{robot_id}.pem"))
    }
    pub fn robot_key(&self, robot_id: &str) -> PathBuf {
        self.dir.join(format!("robot-{robot_id}-key.pem"))
    }
    /// The revocation list every server of this PKI reads (`vlnav
    /// credentials revoke` writes it).
    pub fn revoked(&self) -> PathBuf {
        self.dir.join(REVOCATION_FILE)
    }

    /// A server's TLS: this PKI's server certificate, callers verified against its CA.
    pub fn server_args(&self) -> ServerTlsArgs {
        ServerTlsArgs {
            tls_cert: Some(self.server_cert()),
            tls_key: Some(self.server_key()),
            tls_client_ca: Some(self.ca()),
            tls_revoked: Some(self.revoked()),
        }
    }

    /// A client trusting this PKI's CA, presenting `identity` (certificate, key) if given.
    pub fn client_args(&self, identity: Option<(PathBuf, PathBuf)>) -> ClientTlsArgs {
        let (cert, key) = identity.unzip();
        ClientTlsArgs { tls_ca: Some(self.ca()), tls_client_cert: cert, tls_client_key: key }
    }
}

/// The subject-alternative name of a server name: an IP address or a DNS name.
fn server_san(name: &str) -> anyhow::Result<rcgen::SanType> {
    Ok(match name.parse::<IpAddr>() {
        Ok(ip) => rcgen::SanType::IpAddress(ip),
        Err(_) => rcgen::SanType::DnsName(name.try_into()?),
    })
}

/// Whether two server names are the same: equal addresses, or DNS names
/// equal but for case.
pub fn same_server_name(a: &str, b: &str) -> bool {
    match (a.parse::<IpAddr>(), b.parse::<IpAddr>()) {
        (Ok(x), Ok(y)) => x == y,
        (Err(_), Err(_)) => a.eq_ignore_ascii_case(b),
        _ => false,
    }
}

/// Whether `name` can be a name a client dials a server by, in its
/// certificate: an IP address other than the unspecified ones, or a DNS
/// name (letters, digits and '-' in dot-separated labels of 1–63, 253 in
/// all). The error says what is wrong.
pub fn check_server_name(name: &str) -> anyhow::Result<()> {
    if let Ok(ip) = name.parse::<IpAddr>() {
        if ip.is_unspecified() {
            anyhow::bail!(
                "{name:?} is where a server listens on every address, not one a client dials: give this machine's address or DNS name"
            );
        }
        return Ok(());
    }
    if name.contains("://") || name.contains(':') || name.contains('/') {
        anyhow::bail!(
            "{name:?}: give a DNS name or an IP address alone, without a scheme or a port (e.g. 192.168.1.20 or gateway.lab.example)"
        );
    }
    let label_ok = |l: &str| {
        !l.is_empty()
            && l.len() <= 63
            && !l.starts_with('-')
            && !l.ends_with('-')
            && l.chars().all(|c| c.is_ascii_alphanumeric() || c == '-')
    };
    if name.is_empty() || name.len() > 253 || !name.split('.').all(label_ok) {
        anyhow::bail!(
            "{name:?} is neither an IP address nor a DNS name (dot-separated labels of 1–63 letters, digits or '-', not starting or ending with '-')"
        );
    }
    Ok(())
}

fn validity(params: &mut rcgen::CertificateParams) {
    let now = time::OffsetDateTime::now_utc();
    params.not_before = now - time::Duration::hours(1);
    params.not_after = now + time::Duration::days(DEV_CERT_DAYS);
}

fn write_private(path: &Path, text: &str) -> anyhow::Result<()> {
    #[cfg(unix)]
    {
        use std::io::Write as _;
        use std::os::unix::fs::OpenOptionsExt as _;
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .mode(0o600)
            .open(path)
            .with_context(|| format!("cannot write {}", path.display()))?;
        f.write_all(text.as_bytes())?;
        Ok(())
    }
    #[cfg(not(unix))]
    {
        std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
    }
}

/// Writes a secret (a token) readable by its owner only.
pub fn write_secret(path: &Path, text: &str) -> anyhow::Result<()> {
    write_private(path, text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dev_pki_names_each_robot_in_its_own_certificate_and_is_reused() {
        let dir = tempfile::tempdir().unwrap();
        let pki = DevPki::ensure(dir.path(), &["husky-1"]).unwrap();
        let pem = std::fs::read_to_string(pki.robot_cert("husky-1")).unwrap();
        let der = pem_der(&pem);
        assert_eq!(robot_ids_of_peer(&[der]), vec!["husky-1".to_string()]);
        let server = pem_der(&std::fs::read_to_string(pki.server_cert()).unwrap());
        assert!(robot_ids_of_peer(&[server]).is_empty(), "the server certificate is no robot");
        let ca_before = std::fs::read(pki.ca()).unwrap();
        let again = DevPki::ensure(dir.path(), &["husky-1", "husky-2"]).unwrap();
        assert_eq!(std::fs::read(again.ca()).unwrap(), ca_before, "the CA is reused");
        assert!(again.robot_cert("husky-2").exists());
        assert!(DevPki::ensure(dir.path(), &["../etc"]).is_err(), "a robot id is no path");
    }

    #[test]
    fn extra_server_names_reissue_the_server_certificate_from_the_same_ca_only_when_missing() {
        let dir = tempfile::tempdir().unwrap();
        let pki = DevPki::ensure(dir.path(), &["husky-1"]).unwrap();
        let mut names = pki.server_names();
        names.sort();
        assert_eq!(names, ["127.0.0.1", "::1", "localhost"]);
        let (ca, robot) = (std::fs::read(pki.ca()).unwrap(), std::fs::read(pki.robot_cert("husky-1")).unwrap());
        let before = std::fs::read(pki.server_cert()).unwrap();

        let extra = vec!["192.168.1.20".to_string(), "Gateway.Lab.example".to_string()];
        let pki = DevPki::ensure_named(dir.path(), &[], &extra).unwrap();
        let after = std::fs::read(pki.server_cert()).unwrap();
        assert_ne!(after, before, "a certificate lacking a requested name is issued again");
        let names = pki.server_names();
        for n in ["localhost", "127.0.0.1", "::1", "192.168.1.20", "Gateway.Lab.example"] {
            assert!(names.iter().any(|x| x == n), "{n} missing from {names:?}");
        }
        assert_eq!(std::fs::read(pki.ca()).unwrap(), ca, "the same CA");
        assert_eq!(std::fs::read(pki.robot_cert("husky-1")).unwrap(), robot, "robots' certificates are kept");
        let issuer = |pem: &[u8]| {
            let der = pem_to_der(pem).unwrap();
            let (_, c) = x509_parser::parse_x509_certificate(&der).unwrap();
            c.issuer().to_string()
        };
        assert_eq!(issuer(&after), issuer(&ca), "signed by the CA");

        // Names it already carries (any case, any spelling of the address): kept as it is.
        let again = DevPki::ensure_named(dir.path(), &[], &["gateway.lab.EXAMPLE".into(), "::0:1".into()]).unwrap();
        assert_eq!(std::fs::read(again.server_cert()).unwrap(), after);
        DevPki::ensure(dir.path(), &[]).unwrap();
        assert_eq!(std::fs::read(again.server_cert()).unwrap(), after, "no names asked: kept");
        DevPki::ensure_named(dir.path(), &[], &["10.0.0.7".into()]).unwrap();
        assert!(again.server_names().contains(&"10.0.0.7".to_string()));

        for (bad, says) in [
            ("0.0.0.0", "listens on every address"),
            ("::", "listens on every address"),
            ("https://10.0.0.7:50051", "without a scheme or a port"),
            ("gw.example:50051", "without a scheme or a port"),
            ("", "neither an IP address nor a DNS name"),
            ("-gw.example", "neither an IP address nor a DNS name"),
            ("gw..example", "neither an IP address nor a DNS name"),
            ("gw_1.example", "neither an IP address nor a DNS name"),
        ] {
            let e = DevPki::ensure_named(dir.path(), &[], &[bad.to_string()]).unwrap_err().to_string();
            assert!(e.contains(says), "{bad:?}: {e}");
        }
    }

    #[test]
    fn a_robot_certificate_is_issued_from_an_existing_ca_and_nothing_else_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let e = DevPki::open_ca(&dir.path().join("none")).unwrap_err().to_string();
        assert!(e.contains("is not a directory"), "{e}");
        let e = DevPki::open_ca(dir.path()).unwrap_err().to_string();
        assert!(e.contains("holds no CA") && e.contains("ca.pem is missing"), "{e}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "no CA is created");

        let pki = DevPki::ensure(dir.path(), &[]).unwrap();
        let listing = || {
            let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().path())
                .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap()))
                .collect();
            v.sort();
            v
        };
        let before = listing();
        let out = tempfile::tempdir().unwrap();
        let (cert, key) = (out.path().join("r.pem"), out.path().join("r-key.pem"));
        let ca = DevPki::open_ca(dir.path()).unwrap();
        assert!(ca.issue_robot("../x", &cert, &key).unwrap_err().to_string().contains("robot id \"../x\""));
        ca.issue_robot("husky-7", &cert, &key).unwrap();
        assert_eq!(listing(), before, "the CA's directory is untouched");
        let der = pem_der(&std::fs::read_to_string(&cert).unwrap());
        assert_eq!(robot_ids_of_peer(&[der]), vec!["husky-7".to_string()]);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt as _;
            assert_eq!(std::fs::metadata(&key).unwrap().permissions().mode() & 0o777, 0o600);
        }

        // A key of another CA, a certificate that is no CA, a file that is no PEM.
        let other = tempfile::tempdir().unwrap();
        let other = DevPki::ensure(other.path(), &[]).unwrap();
        std::fs::copy(other.ca_key(), pki.ca_key()).unwrap();
        let e = DevPki::open_ca(dir.path()).unwrap_err().to_string();
        assert!(e.contains("is not the key of") && e.contains("different CAs"), "{e}");
        std::fs::copy(other.server_cert(), pki.ca()).unwrap();
        let e = DevPki::open_ca(dir.path()).unwrap_err().to_string();
        assert!(e.contains("is not a CA certificate"), "{e}");
        std::fs::write(pki.ca(), "hello").unwrap();
        let e = DevPki::open_ca(dir.path()).unwrap_err().to_string();
        assert!(e.contains("is not PEM"), "{e}");
    }

    #[test]
    fn tokens_are_stored_as_hashes() {
        let t = new_token();
        assert_eq!(t.len(), 64);
        assert_ne!(new_token(), t);
        assert_eq!(token_hash("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    }

    #[test]
    fn half_given_tls_settings_are_refused_with_the_missing_flag_named() {
        let only_cert = ServerTlsArgs { tls_cert: Some("c.pem".into()), ..Default::default() };
        assert!(only_cert.load(false).unwrap_err().to_string().contains("--tls-key"));
        let ca_only = ServerTlsArgs { tls_client_ca: Some("ca.pem".into()), ..Default::default() };
        assert!(ca_only.load(false).unwrap_err().to_string().contains("--tls-cert"));
        let revoked_only = ServerTlsArgs { tls_revoked: Some("revoked.toml".into()), ..Default::default() };
        assert!(revoked_only.load(false).unwrap_err().to_string().contains("--tls-revoked needs --tls-cert"));
        let revoked_no_ca = ServerTlsArgs {
            tls_cert: Some("c.pem".into()),
            tls_key: Some("k.pem".into()),
            tls_revoked: Some("revoked.toml".into()),
            ..Default::default()
        };
        assert!(revoked_no_ca.load(false).unwrap_err().to_string().contains("--tls-revoked needs --tls-client-ca"));
        let cert_no_ca =
            ClientTlsArgs { tls_client_cert: Some("c".into()), tls_client_key: Some("k".into()), tls_ca: None };
        assert!(cert_no_ca.load().unwrap_err().to_string().contains("--tls-ca"));
    }

    fn pem_der(pem: &str) -> Vec<u8> {
        pem_to_der(pem.as_bytes()).unwrap()
    }
}
