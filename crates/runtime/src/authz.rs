//! Who may call what, by the identity in the caller's certificate
//! (docs/security.md, "Who may call what").
//!
//! Mutual TLS proves that the CA signed a caller's certificate; a
//! [`CallerPolicy`] says which of those certificates a server answers, method
//! by method: an exact identity (`spiffe://vlnav/service/gateway`), every
//! identity under a prefix (any `spiffe://vlnav/robot/`), or callers that
//! presented no certificate at all (people, who bring a bearer token that the
//! gateway checks next). [`AuthzLayer`] enforces it in front of every service
//! a server hosts; [`crate::serve`] puts it there with the policy its
//! [`crate::ServiceSet`] names.
//!
//! - Health (`grpc.health.v1.Health`) and reflection (v1, v1alpha) stay open
//!   to every caller, so probes and `grpcurl list`/`describe` work.
//! - A method no rule names is refused (fail closed), and so is every method
//!   of a server whose set names no policy.
//! - A refusal is PERMISSION_DENIED naming the caller's identity, the method
//!   and who may call it, with a `warn` audit line.
//! - On a plaintext connection there is no identity to check: the layer lets
//!   the call through. Plaintext is served only on loopback or with an
//!   explicit `--insecure` (see [`crate::server::check_exposure`]), which
//!   already means anyone who reaches the port may call every method. A
//!   server on TLS that asks for no client certificate (no `--tls-client-ca`)
//!   while its policy wants one is refused at start ([`crate::serve`]).

use std::fmt;
use std::sync::Arc;
use std::task::{Context, Poll};

use futures::future::{Either, Ready, ready};
use tonic::Status;
use tonic::body::Body;
use tonic::transport::server::{TcpConnectInfo, TlsConnectInfo};

use crate::security::{GATEWAY_IDENTITY, ROBOT_IDENTITY_PREFIX, SERVICE_IDENTITY_PREFIX, uri_sans};

/// Services every caller may use, whatever the policy.
pub const OPEN_SERVICES: &[&str] =
    &["grpc.health.v1.Health", "grpc.reflection.v1.ServerReflection", "grpc.reflection.v1alpha.ServerReflection"];

/// Which methods a rule covers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Methods {
    /// Every method of every service on the server.
    All,
    /// Every method of one service (`vlnav.v1.MissionService`).
    Service(String),
    /// One method (`vlnav.v1.FleetService/Attach`; a leading '/' is allowed).
    Method(String),
}

impl Methods {
    pub fn service(name: &str) -> Self {
        Self::Service(name.trim_matches('/').to_string())
    }

    pub fn method(path: &str) -> Self {
        Self::Method(path.trim_start_matches('/').to_string())
    }

    fn covers(&self, service: &str, path: &str) -> bool {
        match self {
            Self::All => true,
            Self::Service(s) => s == service,
            Self::Method(m) => m == path,
        }
    }
}

impl fmt::Display for Methods {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::All => f.write_str("*"),
            Self::Service(s) => write!(f, "/{s}/*"),
            Self::Method(m) => write!(f, "/{m}"),
        }
    }
}

/// Who a rule admits.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Callers {
    /// A certificate naming exactly this identity.
    Identity(String),
    /// A certificate naming an identity that starts with this prefix and
    /// has something after it (`spiffe://vlnav/robot/` admits every robot).
    Prefix(String),
    /// A caller on TLS that presented no client certificate (only possible
    /// where the server makes certificates optional, as the gateway does for
    /// people: their bearer token is checked next).
    Uncertified,
}

impl Callers {
    pub fn identity(id: &str) -> Self {
        Self::Identity(id.to_string())
    }

    pub fn prefix(prefix: &str) -> Self {
        Self::Prefix(prefix.to_string())
    }

    /// Every robot (`spiffe://vlnav/robot/<id>`).
    pub fn robots() -> Self {
        Self::prefix(ROBOT_IDENTITY_PREFIX)
    }

    /// Every service (`spiffe://vlnav/service/<name>`).
    pub fn services() -> Self {
        Self::prefix(SERVICE_IDENTITY_PREFIX)
    }

    /// The gateway (`spiffe://vlnav/service/gateway`).
    pub fn gateway() -> Self {
        Self::identity(GATEWAY_IDENTITY)
    }

    fn admits(&self, peer: &Peer) -> bool {
        match (self, peer) {
            (Self::Uncertified, Peer::Uncertified) => true,
            (Self::Identity(want), Peer::Certified(ids)) => ids.iter().any(|id| id == want),
            (Self::Prefix(p), Peer::Certified(ids)) => {
                ids.iter().any(|id| id.strip_prefix(p.as_str()).is_some_and(|rest| !rest.is_empty()))
            }
            _ => false,
        }
    }
}

impl fmt::Display for Callers {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Identity(id) => f.write_str(id),
            Self::Prefix(p) => write!(f, "{p}*"),
            Self::Uncertified => f.write_str("callers without a certificate"),
        }
    }
}

/// Who is calling, as far as the connection tells.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Peer {
    /// No TLS: nothing to check.
    Plaintext,
    /// TLS without a client certificate.
    Uncertified,
    /// TLS with a certificate the CA signed: the `spiffe://` URI SANs of
    /// its leaf (empty when it names none).
    Certified(Vec<String>),
}

impl Peer {
    /// The caller of a request, from the connection info tonic puts into
    /// its extensions.
    pub fn of(extensions: &http::Extensions) -> Self {
        match extensions.get::<TlsConnectInfo<TcpConnectInfo>>() {
            None => Self::Plaintext,
            Some(tls) => match tls.peer_certs() {
                Some(chain) if !chain.is_empty() => Self::Certified(spiffe_ids(&chain[0])),
                _ => Self::Uncertified,
            },
        }
    }
}

impl fmt::Display for Peer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Plaintext => f.write_str("a plaintext caller"),
            Self::Uncertified => f.write_str("a caller without a client certificate"),
            Self::Certified(ids) if ids.is_empty() => f.write_str("a certificate naming no spiffe:// identity"),
            Self::Certified(ids) => f.write_str(&ids.join(" and ")),
        }
    }
}

/// The `spiffe://` URI SANs of a DER certificate (none when it does not parse).
pub fn spiffe_ids(der: &[u8]) -> Vec<String> {
    uri_sans(der).into_iter().filter(|u| u.starts_with("spiffe://")).collect()
}

#[derive(Clone, Debug)]
struct Rule {
    methods: Methods,
    callers: Vec<Callers>,
    reason: String,
}

/// Which callers a server answers, method by method; the first rule that
/// covers a method decides, and a method no rule covers is refused. Health
/// and reflection are always open. [`CallerPolicy::default`] names nobody.
#[derive(Clone, Debug, Default)]
pub struct CallerPolicy {
    rules: Vec<Rule>,
}

impl CallerPolicy {
    pub fn new() -> Self {
        Self::default()
    }

    /// Admits `callers` to `methods`; `reason` ends a refusal ("stages
    /// answer only …"); empty: "it answers only <callers>".
    pub fn allow(mut self, methods: Methods, callers: impl IntoIterator<Item = Callers>, reason: &str) -> Self {
        let callers: Vec<Callers> = callers.into_iter().collect();
        let reason = if reason.is_empty() {
            format!("it answers only {}", callers.iter().map(ToString::to_string).collect::<Vec<_>>().join(" or "))
        } else {
            reason.to_string()
        };
        self.rules.push(Rule { methods, callers, reason });
        self
    }

    /// The pipeline stages' policy: every method answers only the gateway.
    pub fn stages() -> Self {
        Self::new().allow(Methods::All, [Callers::gateway()], &format!("stages answer only {GATEWAY_IDENTITY}"))
    }

    /// Whether some rule wants a certificate (callers without one are
    /// refused there): such a server needs a client CA.
    pub fn wants_certificates(&self) -> bool {
        self.rules.is_empty() || self.rules.iter().any(|r| !r.callers.contains(&Callers::Uncertified))
    }

    /// `Ok` when `peer` may call `path` (`/package.Service/Method`), else
    /// PERMISSION_DENIED naming the caller, the method and who may call it.
    pub fn check(&self, path: &str, peer: &Peer) -> Result<(), Status> {
        if *peer == Peer::Plaintext {
            return Ok(());
        }
        let trimmed = path.trim_start_matches('/');
        let service = trimmed.split_once('/').map_or(trimmed, |(s, _)| s);
        if OPEN_SERVICES.contains(&service) {
            return Ok(());
        }
        let reason = match self.rules.iter().find(|r| r.methods.covers(service, trimmed)) {
            Some(rule) if rule.callers.iter().any(|c| c.admits(peer)) => return Ok(()),
            Some(rule) => rule.reason.as_str(),
            None if self.rules.is_empty() => "this server answers no caller but health and reflection",
            None => "no rule of this server names it (unknown methods are refused)",
        };
        Err(Status::permission_denied(format!("{peer} may not call /{trimmed}; {reason}")))
    }
}

impl fmt::Display for CallerPolicy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.rules.is_empty() {
            return f.write_str("nobody but health and reflection");
        }
        for (i, r) in self.rules.iter().enumerate() {
            let callers: Vec<String> = r.callers.iter().map(ToString::to_string).collect();
            write!(f, "{}{}: {}", if i > 0 { "; " } else { "" }, r.methods, callers.join(", "))?;
        }
        Ok(())
    }
}

/// Enforces a [`CallerPolicy`] in front of the services it wraps.
#[derive(Clone, Debug)]
pub struct AuthzLayer {
    policy: Arc<CallerPolicy>,
}

impl AuthzLayer {
    pub fn new(policy: CallerPolicy) -> Self {
        Self { policy: Arc::new(policy) }
    }
}

impl<S> tower::Layer<S> for AuthzLayer {
    type Service = Authz<S>;
    fn layer(&self, inner: S) -> Authz<S> {
        Authz { inner, policy: self.policy.clone() }
    }
}

/// A service behind [`AuthzLayer`].
#[derive(Clone, Debug)]
pub struct Authz<S> {
    inner: S,
    policy: Arc<CallerPolicy>,
}

impl<S, B> tower::Service<http::Request<B>> for Authz<S>
where
    S: tower::Service<http::Request<B>, Response = http::Response<Body>>,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = Either<Ready<Result<S::Response, S::Error>>, S::Future>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        let peer = Peer::of(req.extensions());
        match self.policy.check(req.uri().path(), &peer) {
            Ok(()) => Either::Right(self.inner.call(req)),
            Err(status) => {
                tracing::warn!(caller = %peer, method = %req.uri().path(), "refused: {}", status.message());
                Either::Left(ready(Ok(status.into_http())))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::security::{DevPki, pem_to_der, robot_identity};

    fn certified(ids: &[&str]) -> Peer {
        Peer::Certified(ids.iter().map(|s| s.to_string()).collect())
    }

    const PLAN: &str = "/vlnav.v1.PlannerService/Plan";

    #[test]
    fn stages_answer_only_the_gateway_and_say_who_was_refused_for_what() {
        let p = CallerPolicy::stages();
        assert!(p.check(PLAN, &certified(&[GATEWAY_IDENTITY])).is_ok());
        let robot = certified(&["spiffe://vlnav/robot/husky-1"]);
        for path in [
            PLAN,
            "/vlnav.v1.DetectorService/GetModelInfo",
            "/vlnav.v1.ReidService/ListGallery",
            "/vlnav.v1.LocalPlannerService/ResetRobot",
        ] {
            let e = p.check(path, &robot).unwrap_err();
            assert_eq!(e.code(), tonic::Code::PermissionDenied);
            assert_eq!(
                e.message(),
                format!("spiffe://vlnav/robot/husky-1 may not call {path}; stages answer only {GATEWAY_IDENTITY}")
            );
        }
        for other in [
            certified(&["spiffe://vlnav/service/planner"]),
            certified(&["spiffe://vlnav/service/gateway-2"]),
            certified(&["spiffe://vlnav/service/gatewa"]),
            certified(&[]),
            Peer::Uncertified,
        ] {
            let e = p.check(PLAN, &other).unwrap_err();
            assert_eq!(e.code(), tonic::Code::PermissionDenied, "{other}");
            assert!(e.message().starts_with(&format!("{other} may not call {PLAN}")), "{}", e.message());
        }
        // One of several identities suffices.
        assert!(p.check(PLAN, &certified(&["spiffe://vlnav/robot/x", GATEWAY_IDENTITY])).is_ok());
    }

    #[test]
    fn health_and_reflection_stay_open_and_plaintext_is_not_checked() {
        let nobody = CallerPolicy::new();
        let robot = certified(&["spiffe://vlnav/robot/husky-1"]);
        for path in [
            "/grpc.health.v1.Health/Check",
            "/grpc.health.v1.Health/Watch",
            "/grpc.reflection.v1.ServerReflection/ServerReflectionInfo",
            "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
        ] {
            for peer in [robot.clone(), Peer::Uncertified, certified(&[])] {
                assert!(nobody.check(path, &peer).is_ok(), "{path} for {peer}");
                assert!(CallerPolicy::stages().check(path, &peer).is_ok(), "{path} for {peer}");
            }
        }
        let e = nobody.check(PLAN, &certified(&[GATEWAY_IDENTITY])).unwrap_err();
        assert!(e.message().contains("answers no caller but health and reflection"), "{}", e.message());
        assert!(nobody.check(PLAN, &Peer::Plaintext).is_ok(), "plaintext carries no identity to check");
        // Look-alikes of the open services are not open.
        assert!(nobody.check("/grpc.health.v1.HealthX/Check", &robot).is_err());
        assert!(nobody.check("/grpc.health.v2.Health/Check", &robot).is_err());
    }

    #[test]
    fn the_first_rule_covering_a_method_decides_and_unknown_methods_are_refused() {
        let p = CallerPolicy::new()
            .allow(Methods::method("/vlnav.v1.FleetService/Attach"), [Callers::robots(), Callers::Uncertified], "")
            .allow(Methods::service("vlnav.v1.MissionService"), [Callers::Uncertified, Callers::services()], "")
            .allow(Methods::method("vlnav.v1.FleetService/ListRobots"), [Callers::Uncertified], "people only");
        let robot = certified(&[&robot_identity("husky-2")]);
        assert!(p.check("/vlnav.v1.FleetService/Attach", &robot).is_ok());
        assert!(p.check("/vlnav.v1.FleetService/Attach", &Peer::Uncertified).is_ok());
        let e = p.check("/vlnav.v1.FleetService/Attach", &certified(&[GATEWAY_IDENTITY])).unwrap_err();
        assert_eq!(
            e.message(),
            "spiffe://vlnav/service/gateway may not call /vlnav.v1.FleetService/Attach; it answers only \
             spiffe://vlnav/robot/* or callers without a certificate"
        );
        // A bare prefix is no identity.
        assert!(p.check("/vlnav.v1.FleetService/Attach", &certified(&["spiffe://vlnav/robot/"])).is_err());
        assert!(p.check("/vlnav.v1.MissionService/SubmitMission", &Peer::Uncertified).is_ok());
        assert!(p.check("/vlnav.v1.MissionService/SubmitMission", &certified(&[GATEWAY_IDENTITY])).is_ok());
        assert!(p.check("/vlnav.v1.MissionService/SubmitMission", &robot).is_err());
        let e = p.check("/vlnav.v1.FleetService/ListRobots", &robot).unwrap_err();
        assert!(e.message().ends_with("; people only"), "{}", e.message());
        let e = p.check("/vlnav.v1.FleetService/Detach", &Peer::Uncertified).unwrap_err();
        assert!(e.message().contains("unknown methods are refused"), "{}", e.message());
        // Paths that are not gRPC paths are refused, not a panic.
        for odd in ["", "/", "//", "vlnav.v1.MissionService", "/vlnav.v1.MissionService", "/a/b/c"] {
            assert!(p.check(odd, &robot).is_err(), "{odd:?}");
        }
        assert!(p.to_string().contains("/vlnav.v1.FleetService/Attach: spiffe://vlnav/robot/*"), "{p}");
    }

    #[test]
    fn certificates_are_needed_unless_every_rule_admits_callers_without_one() {
        assert!(CallerPolicy::new().wants_certificates());
        assert!(CallerPolicy::stages().wants_certificates());
        let people = CallerPolicy::new().allow(Methods::All, [Callers::Uncertified, Callers::robots()], "");
        assert!(!people.wants_certificates());
    }

    #[test]
    fn the_identity_is_read_from_the_leaf_certificate_of_the_dev_pki() {
        let dir = tempfile::tempdir().unwrap();
        let pki = DevPki::ensure(dir.path(), &["husky-1"]).unwrap();
        let der = |p: std::path::PathBuf| pem_to_der(&std::fs::read(p).unwrap()).unwrap();
        assert_eq!(spiffe_ids(&der(pki.robot_cert("husky-1"))), vec!["spiffe://vlnav/robot/husky-1".to_string()]);
        assert_eq!(spiffe_ids(&der(pki.gateway_cert())), vec![GATEWAY_IDENTITY.to_string()]);
        assert_eq!(spiffe_ids(&der(pki.server_cert())), vec!["spiffe://vlnav/service/server".to_string()]);
        let (cert, key) = (dir.path().join("planner.pem"), dir.path().join("planner-key.pem"));
        pki.issue_service("planner", &["planner".into(), "127.0.0.1".into()], &cert, &key).unwrap();
        assert_eq!(spiffe_ids(&der(cert)), vec!["spiffe://vlnav/service/planner".to_string()]);
        // The CA names nobody; bytes that are no certificate name nobody either.
        assert!(spiffe_ids(&der(pki.ca())).is_empty());
        assert!(spiffe_ids(b"not a certificate").is_empty());
        assert!(spiffe_ids(&[]).is_empty());
    }

    #[test]
    fn a_request_without_tls_info_is_plaintext() {
        let ext = http::Extensions::new();
        assert_eq!(Peer::of(&ext), Peer::Plaintext);
    }
}
