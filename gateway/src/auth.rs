//! Who may call the gateway (docs/security.md): bearer tokens, stored as
//! SHA-256 hashes in a TOML file that is read again when it changes (a
//! rotated Kubernetes Secret, an edited file), and the tower layer that
//! checks them before any handler runs.
//!
//! Roles: `viewer` may get, list and watch missions and list robots;
//! `operator` may also submit, cancel and answer. A token may be scoped to
//! some robots and may expire. Health and reflection need nothing, so probes
//! and `grpcurl list`/`describe` keep working. Robots attach with their
//! certificate, not a token (checked by the Attach handler).
//!
//! Before tokens, [`caller_policy`] says which certificates the gateway
//! answers (`vlnav_runtime::authz`): a robot's only on Attach, people's
//! calls come without one.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};
use std::task::{Context, Poll};
use std::time::{Duration, Instant, SystemTime};

use futures::future::BoxFuture;
use serde::{Deserialize, Serialize};
use tonic::Status;
use tonic::body::Body;
use tonic::server::NamedService;
use vlnav_runtime::authz::{CallerPolicy, Callers, Methods};

/// How often a request may look at the token file again.
pub(crate) const RELOAD_EVERY: Duration = Duration::from_secs(1);

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
/// What a token's holder may do (docs/security.md).
pub enum Role {
    /// Reads missions and robots.
    Viewer,
    /// Also submits, answers and cancels missions.
    Operator,
}

impl Role {
    fn as_str(self) -> &'static str {
        match self {
            Role::Viewer => "viewer",
            Role::Operator => "operator",
        }
    }
}

/// One entry of the token file.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TokenEntry {
    /// Who holds it: recorded as the caller in the audit trail.
    pub name: String,
    /// What its holder may do.
    pub role: Role,
    /// SHA-256 of the token, hex (`vlnav_runtime::security::token_hash`).
    pub sha256: String,
    /// Robots it may act on; absent: every robot.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robots: Option<Vec<String>>,
    /// Unix time after which it is refused; absent: never.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub expires_unix: Option<f64>,
}

/// The token file (`--tokens-file`, TOML): one `[[token]]` per entry.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TokenFile {
    /// Every token the gateway accepts.
    #[serde(default, rename = "token")]
    pub tokens: Vec<TokenEntry>,
}

impl TokenFile {
    /// The file read from `text`; an entry whose `sha256` is not 64 hex
    /// digits is refused (a token pasted in place of its hash), naming `path`.
    pub fn parse(text: &str, path: &Path) -> anyhow::Result<Self> {
        let file: TokenFile = toml::from_str(text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        for t in &file.tokens {
            if t.sha256.len() != 64 || !t.sha256.chars().all(|c| c.is_ascii_hexdigit()) {
                anyhow::bail!(
                    "{}: token '{}' has sha256 = {:?}; write the 64 hex digits of the token's SHA-256, never the token",
                    path.display(),
                    t.name,
                    t.sha256
                );
            }
        }
        Ok(file)
    }

    /// The file as written to disk, with a header saying how to edit it.
    pub fn to_toml(&self) -> String {
        let body = toml::to_string(self).unwrap_or_default();
        format!(
            "# vlnav bearer tokens (docs/security.md): the SHA-256 of each token, never the token.\n\
             # Edit or replace this file to add, rotate or revoke tokens; the gateway reads it again within a second.\n\n{body}"
        )
    }
}

/// The authenticated caller of a request, put into its extensions by
/// [`AuthLayer`] for handlers to scope and audit.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Caller {
    pub(crate) name: String,
    pub(crate) role: Role,
    pub(crate) robots: Option<Vec<String>>,
}

impl Caller {
    /// The caller when the gateway runs without authentication.
    pub(crate) fn anonymous() -> Self {
        Self { name: "anonymous (no authentication configured)".into(), role: Role::Operator, robots: None }
    }

    pub(crate) fn may_act_on(&self, robot_id: &str) -> bool {
        self.robots.as_ref().is_none_or(|r| r.iter().any(|x| x == robot_id))
    }

    /// PERMISSION_DENIED unless the caller may act on `robot_id`.
    pub(crate) fn check_robot(&self, robot_id: &str, what: &str) -> Result<(), Status> {
        if self.may_act_on(robot_id) {
            return Ok(());
        }
        Err(Status::permission_denied(format!(
            "{what} robot '{robot_id}' is not allowed to '{}': its token is scoped to robots [{}]",
            self.name,
            self.robots.as_deref().unwrap_or_default().join(", ")
        )))
    }

    /// The caller a handler sees (anonymous when no layer ran).
    pub(crate) fn of<T>(request: &tonic::Request<T>) -> Caller {
        request.extensions().get::<Caller>().cloned().unwrap_or_else(Caller::anonymous)
    }
}

/// Tokens by hash, read from a file and read again when it changes.
pub(crate) struct TokenStore {
    path: PathBuf,
    state: RwLock<Loaded>,
    checked: Mutex<Instant>,
}

/// A file's modification time and length: whether it changed.
type FileStamp = Option<(SystemTime, u64)>;

struct Loaded {
    by_hash: HashMap<String, TokenEntry>,
    stamp: FileStamp,
}

impl TokenStore {
    /// Reads `path`; an unreadable or malformed file is an error at start.
    pub(crate) fn open(path: &Path) -> anyhow::Result<Arc<Self>> {
        let (by_hash, stamp) = Self::read(path)?;
        tracing::info!(path = %path.display(), tokens = by_hash.len(), "bearer tokens loaded");
        Ok(Arc::new(Self {
            path: path.to_path_buf(),
            state: RwLock::new(Loaded { by_hash, stamp }),
            checked: Mutex::new(Instant::now()),
        }))
    }

    fn read(path: &Path) -> anyhow::Result<(HashMap<String, TokenEntry>, FileStamp)> {
        let stamp = file_stamp(path);
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("cannot read the token file {}: {e}", path.display()))?;
        let file = TokenFile::parse(&text, path)?;
        Ok((file.tokens.into_iter().map(|t| (t.sha256.to_ascii_lowercase(), t)).collect(), stamp))
    }

    /// Reads the file again if it changed since the last look (at most once
    /// per [`RELOAD_EVERY`]). A broken new file keeps the old tokens.
    fn refresh(&self) {
        {
            let mut checked = self.checked.lock().unwrap_or_else(|e| e.into_inner());
            if checked.elapsed() < RELOAD_EVERY {
                return;
            }
            *checked = Instant::now();
        }
        let stamp = file_stamp(&self.path);
        if stamp == self.state.read().unwrap_or_else(|e| e.into_inner()).stamp {
            return;
        }
        match Self::read(&self.path) {
            Ok((by_hash, stamp)) => {
                tracing::info!(path = %self.path.display(), tokens = by_hash.len(), "bearer tokens reloaded");
                *self.state.write().unwrap_or_else(|e| e.into_inner()) = Loaded { by_hash, stamp };
            }
            Err(e) => tracing::error!("keeping the previous tokens: {e:#}"),
        }
    }

    /// The caller a bearer token belongs to, or UNAUTHENTICATED saying why not.
    pub(crate) fn authenticate(&self, token: &str) -> Result<Caller, Status> {
        self.refresh();
        let hash = vlnav_runtime::security::token_hash(token);
        let state = self.state.read().unwrap_or_else(|e| e.into_inner());
        let entry = state.by_hash.get(&hash).ok_or_else(|| {
            Status::unauthenticated("the bearer token is not known to this gateway (mistyped, revoked or rotated away)")
        })?;
        if let Some(exp) = entry.expires_unix {
            let now = SystemTime::now().duration_since(SystemTime::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0);
            if now > exp {
                return Err(Status::unauthenticated(format!(
                    "the token of '{}' expired at Unix time {exp:.0}; ask for a new one",
                    entry.name
                )));
            }
        }
        Ok(Caller { name: entry.name.clone(), role: entry.role, robots: entry.robots.clone() })
    }
}

fn file_stamp(path: &Path) -> FileStamp {
    let meta = std::fs::metadata(path).ok()?;
    Some((meta.modified().ok()?, meta.len()))
}

/// What a gRPC method needs (fails closed: unknown methods need an operator).
pub(crate) enum Needs {
    /// Health, reflection: nothing.
    Nothing,
    /// A robot's certificate, checked by the handler.
    RobotCertificate,
    Role(Role),
}

pub(crate) fn needs(path: &str) -> Needs {
    let (service, method) = path.trim_start_matches('/').split_once('/').unwrap_or((path, ""));
    match (service, method) {
        ("grpc.health.v1.Health", _)
        | ("grpc.reflection.v1.ServerReflection", _)
        | ("grpc.reflection.v1alpha.ServerReflection", _) => Needs::Nothing,
        ("vlnav.v1.FleetService", "Attach") => Needs::RobotCertificate,
        ("vlnav.v1.FleetService", "ListRobots")
        | ("vlnav.v1.MissionService", "GetMission" | "ListMissions" | "WatchMission") => Needs::Role(Role::Viewer),
        _ => Needs::Role(Role::Operator),
    }
}

/// Which certificates the gateway answers, checked before tokens on TLS
/// (`vlnav_runtime::authz`). People call without a certificate and their
/// token decides; a robot's certificate is good only for Attach, where the
/// handler checks that it names the robot attaching (a certificate-less
/// Attach reaches the handler too, which refuses it naming the identity it
/// needs); services' certificates may call the rest with a token.
pub(crate) fn caller_policy() -> CallerPolicy {
    CallerPolicy::new()
        .allow(
            Methods::method("vlnav.v1.FleetService/Attach"),
            [Callers::robots(), Callers::Uncertified],
            "Attach answers only a robot's certificate (spiffe://vlnav/robot/<robot_id>), each robot as itself",
        )
        .allow(Methods::service("vlnav.v1.MissionService"), [Callers::Uncertified, Callers::services()], PEOPLE)
        .allow(Methods::method("vlnav.v1.FleetService/ListRobots"), [Callers::Uncertified, Callers::services()], PEOPLE)
}

const PEOPLE: &str = "a robot's certificate is good only for FleetService/Attach; people call with a bearer token \
                      and no certificate";

/// Checks the bearer token of every request to the wrapped services.
#[derive(Clone)]
pub(crate) struct AuthLayer {
    tokens: Option<Arc<TokenStore>>,
}

impl AuthLayer {
    /// `None`: no authentication (every caller is [`Caller::anonymous`]).
    pub(crate) fn new(tokens: Option<Arc<TokenStore>>) -> Self {
        Self { tokens }
    }

    /// Whether callers authenticate (else everyone is anonymous).
    pub(crate) fn is_on(&self) -> bool {
        self.tokens.is_some()
    }

    /// Wraps one tonic service.
    pub(crate) fn wrap<S>(&self, inner: S) -> Authorized<S> {
        Authorized { inner, tokens: self.tokens.clone() }
    }
}

impl<S> tower::Layer<S> for AuthLayer {
    type Service = Authorized<S>;
    fn layer(&self, inner: S) -> Authorized<S> {
        self.wrap(inner)
    }
}

#[derive(Clone)]
pub(crate) struct Authorized<S> {
    inner: S,
    tokens: Option<Arc<TokenStore>>,
}

impl<S: NamedService> NamedService for Authorized<S> {
    const NAME: &'static str = S::NAME;
}

fn bearer(headers: &http::HeaderMap) -> Option<&str> {
    let value = headers.get(http::header::AUTHORIZATION)?.to_str().ok()?.trim();
    let (scheme, token) = value.split_once(' ')?;
    scheme.eq_ignore_ascii_case("bearer").then(|| token.trim()).filter(|t| !t.is_empty())
}

fn method_name(path: &str) -> &str {
    path.rsplit('/').next().unwrap_or(path)
}

/// The caller of a request to `path` with `headers`, or the status refusing it.
pub(crate) fn authorize(tokens: &TokenStore, path: &str, headers: &http::HeaderMap) -> Result<Option<Caller>, Status> {
    let role = match needs(path) {
        Needs::Nothing | Needs::RobotCertificate => return Ok(None),
        Needs::Role(r) => r,
    };
    let token = bearer(headers).ok_or_else(|| {
        Status::unauthenticated(format!(
            "{} needs a bearer token of the {} role: send the header `authorization: Bearer <token>` \
             (`vlnav up` writes one to <data-dir>/security/operator.token)",
            method_name(path),
            role.as_str()
        ))
    })?;
    let caller = tokens.authenticate(token)?;
    if caller.role < role {
        return Err(Status::permission_denied(format!(
            "{} needs the {} role; the token of '{}' has the {} role",
            method_name(path),
            role.as_str(),
            caller.name,
            caller.role.as_str()
        )));
    }
    Ok(Some(caller))
}

impl<S> tower::Service<http::Request<Body>> for Authorized<S>
where
    S: tower::Service<http::Request<Body>, Response = http::Response<Body>> + Clone + Send + 'static,
    S::Future: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = BoxFuture<'static, Result<Self::Response, Self::Error>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, mut req: http::Request<Body>) -> Self::Future {
        if let Some(tokens) = &self.tokens {
            match authorize(tokens, req.uri().path(), req.headers()) {
                Ok(Some(caller)) => {
                    req.extensions_mut().insert(caller);
                }
                Ok(None) => {}
                Err(status) => {
                    tracing::warn!(method = %req.uri().path(), "refused: {}", status.message());
                    return Box::pin(async move { Ok(status.into_http()) });
                }
            }
        }
        let clone = self.inner.clone();
        let mut inner = std::mem::replace(&mut self.inner, clone);
        Box::pin(async move { inner.call(req).await })
    }
}

/// Writes a token file with an operator and a viewer token for `vlnav up`,
/// and the tokens themselves (owner-only) beside it, unless it exists.
pub fn ensure_dev_tokens(dir: &Path) -> anyhow::Result<PathBuf> {
    let file = dir.join("tokens.toml");
    if file.exists() && dir.join("operator.token").exists() {
        return Ok(file);
    }
    std::fs::create_dir_all(dir)?;
    let mut tokens = Vec::new();
    for role in [Role::Operator, Role::Viewer] {
        let token = vlnav_runtime::security::new_token();
        vlnav_runtime::security::write_secret(&dir.join(format!("{}.token", role.as_str())), &format!("{token}\n"))?;
        tokens.push(TokenEntry {
            name: format!("local-{}", role.as_str()),
            role,
            sha256: vlnav_runtime::security::token_hash(&token),
            robots: None,
            expires_unix: None,
        });
    }
    std::fs::write(&file, TokenFile { tokens }.to_toml())?;
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vlnav_runtime::security::token_hash;

    fn store(entries: Vec<TokenEntry>) -> (tempfile::TempDir, Arc<TokenStore>) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tokens.toml");
        std::fs::write(&path, TokenFile { tokens: entries }.to_toml()).unwrap();
        let s = TokenStore::open(&path).unwrap();
        (dir, s)
    }

    fn entry(name: &str, role: Role, token: &str) -> TokenEntry {
        TokenEntry { name: name.into(), role, sha256: token_hash(token), robots: None, expires_unix: None }
    }

    fn headers(token: Option<&str>) -> http::HeaderMap {
        let mut h = http::HeaderMap::new();
        if let Some(t) = token {
            h.insert(http::header::AUTHORIZATION, format!("Bearer {t}").parse().unwrap());
        }
        h
    }

    const SUBMIT: &str = "/vlnav.v1.MissionService/SubmitMission";
    const GET: &str = "/vlnav.v1.MissionService/GetMission";

    #[test]
    fn roles_decide_what_a_token_may_call() {
        let (_d, s) =
            store(vec![entry("ops", Role::Operator, "op-secret"), entry("eyes", Role::Viewer, "view-secret")]);
        let no = authorize(&s, SUBMIT, &headers(None)).unwrap_err();
        assert_eq!(no.code(), tonic::Code::Unauthenticated);
        assert!(no.message().contains("operator"), "{}", no.message());
        let viewer = authorize(&s, SUBMIT, &headers(Some("view-secret"))).unwrap_err();
        assert_eq!(viewer.code(), tonic::Code::PermissionDenied);
        assert!(viewer.message().contains("'eyes'") && viewer.message().contains("viewer"));
        assert_eq!(authorize(&s, GET, &headers(Some("view-secret"))).unwrap().unwrap().name, "eyes");
        assert_eq!(authorize(&s, SUBMIT, &headers(Some("op-secret"))).unwrap().unwrap().role, Role::Operator);
        assert_eq!(authorize(&s, GET, &headers(Some("op-secret"))).unwrap().unwrap().name, "ops");
        let wrong = authorize(&s, GET, &headers(Some("guess"))).unwrap_err();
        assert_eq!(wrong.code(), tonic::Code::Unauthenticated);
        assert!(authorize(&s, "/grpc.health.v1.Health/Check", &headers(None)).unwrap().is_none());
        assert!(
            authorize(&s, "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo", &headers(None)).is_ok()
        );
        let unknown = authorize(&s, "/vlnav.v1.MissionService/SomethingNew", &headers(Some("view-secret")));
        assert_eq!(unknown.unwrap_err().code(), tonic::Code::PermissionDenied, "unknown methods need an operator");
    }

    #[test]
    fn expired_tokens_are_refused_and_scopes_limit_robots() {
        let mut old = entry("old", Role::Operator, "old-secret");
        old.expires_unix = Some(1.0);
        let mut scoped = entry("scoped", Role::Operator, "scoped-secret");
        scoped.robots = Some(vec!["husky-1".into()]);
        let (_d, s) = store(vec![old, scoped]);
        let e = authorize(&s, SUBMIT, &headers(Some("old-secret"))).unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        assert!(e.message().contains("expired"));
        let c = authorize(&s, SUBMIT, &headers(Some("scoped-secret"))).unwrap().unwrap();
        assert!(c.check_robot("husky-1", "submitting to").is_ok());
        let denied = c.check_robot("husky-2", "submitting to").unwrap_err();
        assert_eq!(denied.code(), tonic::Code::PermissionDenied);
        assert!(denied.message().contains("husky-1"), "{}", denied.message());
    }

    #[test]
    fn a_rewritten_token_file_is_read_again_and_a_broken_one_keeps_the_old_tokens() {
        let (dir, s) = store(vec![entry("a", Role::Operator, "first")]);
        assert!(s.authenticate("first").is_ok());
        let path = dir.path().join("tokens.toml");
        std::fs::write(&path, TokenFile { tokens: vec![entry("b", Role::Operator, "second-token")] }.to_toml())
            .unwrap();
        std::thread::sleep(RELOAD_EVERY + Duration::from_millis(50));
        assert_eq!(s.authenticate("first").unwrap_err().code(), tonic::Code::Unauthenticated, "revoked");
        assert_eq!(s.authenticate("second-token").unwrap().name, "b");
        std::fs::write(&path, "this is not toml [").unwrap();
        std::thread::sleep(RELOAD_EVERY + Duration::from_millis(50));
        assert_eq!(s.authenticate("second-token").unwrap().name, "b", "a broken file keeps the tokens");
    }

    #[test]
    fn plaintext_tokens_in_the_file_are_refused_at_start() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.toml");
        std::fs::write(&path, "[[token]]\nname = \"x\"\nrole = \"operator\"\nsha256 = \"hunter2\"\n").unwrap();
        let e = TokenStore::open(&path).err().unwrap().to_string();
        assert!(e.contains("never the token"), "{e}");
    }

    #[test]
    fn dev_tokens_are_written_once_with_the_secrets_beside_them() {
        let dir = tempfile::tempdir().unwrap();
        let file = ensure_dev_tokens(dir.path()).unwrap();
        let op = vlnav_runtime::security::read_token(&dir.path().join("operator.token")).unwrap();
        let s = TokenStore::open(&file).unwrap();
        assert_eq!(s.authenticate(&op).unwrap().role, Role::Operator);
        assert!(!std::fs::read_to_string(&file).unwrap().contains(&op), "the file holds hashes only");
        ensure_dev_tokens(dir.path()).unwrap();
        assert_eq!(vlnav_runtime::security::read_token(&dir.path().join("operator.token")).unwrap(), op);
    }

    #[test]
    fn a_robot_certificate_is_good_only_for_attach_and_people_come_without_one() {
        use vlnav_runtime::authz::Peer;
        let p = caller_policy();
        let robot = Peer::Certified(vec!["spiffe://vlnav/robot/husky-1".into()]);
        let gateway = Peer::Certified(vec![vlnav_runtime::security::GATEWAY_IDENTITY.into()]);
        const ATTACH: &str = "/vlnav.v1.FleetService/Attach";
        assert!(p.check(ATTACH, &robot).is_ok());
        assert!(p.check(ATTACH, &Peer::Uncertified).is_ok(), "the handler refuses it, naming the identity");
        let e = p.check(ATTACH, &gateway).unwrap_err();
        assert!(e.message().contains("Attach answers only a robot's certificate"), "{}", e.message());
        for path in [SUBMIT, GET, "/vlnav.v1.MissionService/CancelMission", "/vlnav.v1.FleetService/ListRobots"] {
            assert!(p.check(path, &Peer::Uncertified).is_ok(), "{path}: the token decides");
            assert!(p.check(path, &gateway).is_ok(), "{path}: a service, then its token");
            let e = p.check(path, &robot).unwrap_err();
            assert_eq!(e.code(), tonic::Code::PermissionDenied);
            assert!(e.message().starts_with(&format!("spiffe://vlnav/robot/husky-1 may not call {path}")), "{e:?}");
        }
        assert!(p.check("/vlnav.v1.FleetService/Detach", &Peer::Uncertified).is_err(), "unknown: refused");
        assert!(p.check("/grpc.health.v1.Health/Check", &robot).is_ok());
    }
}
