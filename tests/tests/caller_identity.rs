//! Who may call what (docs/security.md, "Who may call what"), over the real
//! stack with mutual TLS: every credential kind the project issues — each
//! robot, the gateway, each stage, the shared development server
//! certificate, the operator and viewer tokens, a robot's certificate with
//! an operator token, nothing — calls every method of every server (listed
//! from the proto descriptor set, so a new method is covered without
//! touching this file) and gets exactly the answer the matrix below says:
//! refused by the caller policy (PERMISSION_DENIED naming the identity and
//! the method), refused at the TLS handshake, refused by the token layer, or
//! through to the handler.

mod common;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use common::RawCodec;
use prost::Message;
use tonic::{Code, Status};
use vlnav_e2e::TestStack;
use vlnav_runtime::client::{TracedChannel, channel_with};
use vlnav_runtime::security::{ClientSecurity, ClientTls, GATEWAY_IDENTITY, service_identity};

/// The stage servers, as `vlnav up` and the Kubernetes credentials name them.
const STAGES: [(&str, &str); 7] = [
    ("IngressService", "ingress"),
    ("PlannerService", "planner"),
    ("DetectorService", "detector"),
    ("ReidService", "reid"),
    ("SegmenterService", "segmenter"),
    ("SubgoalService", "subgoal"),
    ("LocalPlannerService", "local-planner"),
];

/// What a caller brings.
struct Credential {
    name: String,
    /// Certificate and key files.
    cert: Option<(PathBuf, PathBuf)>,
    /// The identity its certificate names.
    identity: Option<String>,
    token: Option<String>,
}

/// The answer a call must get.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Expect {
    /// The caller policy: PERMISSION_DENIED "<identity> may not call <method>; …".
    Denied,
    /// Stages ask every caller for a certificate: the handshake fails.
    NoHandshake,
    /// The gateway's token layer: no token.
    Unauthenticated,
    /// The gateway's token layer: a viewer's token on an operator's method.
    WrongRole,
    /// Past every check, to the handler (which may still refuse the empty request).
    Through,
}

fn is_viewer_method(service: &str, method: &str) -> bool {
    matches!(
        (service, method),
        ("FleetService", "ListRobots") | ("MissionService", "GetMission" | "ListMissions" | "WatchMission")
    )
}

/// The matrix: what `c` gets from `service/method`.
fn expect(c: &Credential, service: &str, method: &str) -> Expect {
    let robot = c.identity.as_deref().is_some_and(|i| i.starts_with("spiffe://vlnav/robot/"));
    match service {
        "MissionService" | "FleetService" if method == "Attach" => match &c.identity {
            // Robots, and callers without a certificate (whom the handler
            // refuses naming the robot identity needed; the empty request
            // here is refused before that, as not an EdgeHello).
            None => Expect::Through,
            Some(_) if robot => Expect::Through,
            Some(_) => Expect::Denied,
        },
        "MissionService" | "FleetService" => match (&c.identity, &c.token) {
            (Some(_), _) if robot => Expect::Denied,
            (_, None) => Expect::Unauthenticated,
            (_, Some(t)) if t.as_str() == "viewer" && !is_viewer_method(service, method) => Expect::WrongRole,
            (_, Some(_)) => Expect::Through,
        },
        _ => match &c.identity {
            None => Expect::NoHandshake,
            Some(id) if id == GATEWAY_IDENTITY => Expect::Through,
            Some(_) => Expect::Denied,
        },
    }
}

/// One call with an empty request (one empty message on a stream); `Ok` or
/// the status it ended with.
async fn call(channel: TracedChannel, path: &str, streaming: bool) -> Result<(), Status> {
    let mut grpc = tonic::client::Grpc::new(channel);
    grpc.ready().await.map_err(|e| Status::unavailable(format!("not ready: {e}")))?;
    let route = http::uri::PathAndQuery::try_from(path).unwrap();
    if streaming {
        let msgs = tokio_stream::iter(vec![Vec::<u8>::new()]);
        let mut stream = grpc.streaming(tonic::Request::new(msgs), route, RawCodec).await?.into_inner();
        stream.message().await.map(|_| ())
    } else {
        grpc.unary(tonic::Request::new(Vec::<u8>::new()), route, RawCodec).await.map(|_| ())
    }
}

/// Whether `result` is the answer `want` of `c` calling `path`.
fn check(c: &Credential, path: &str, want: Expect, result: &Result<(), Status>) -> Result<(), String> {
    let ok = match (want, result) {
        (Expect::Denied, Err(s)) => {
            let who = c.identity.as_deref().unwrap_or("a caller without a client certificate");
            s.code() == Code::PermissionDenied && s.message().starts_with(&format!("{who} may not call {path}; "))
        }
        (Expect::NoHandshake, Err(s)) => common::is_crash(s.code()),
        (Expect::Unauthenticated, Err(s)) => {
            s.code() == Code::Unauthenticated && s.message().contains("authorization: Bearer")
        }
        (Expect::WrongRole, Err(s)) => s.code() == Code::PermissionDenied && s.message().contains("operator role"),
        (Expect::Through, Ok(())) => true,
        (Expect::Through, Err(s)) => {
            !matches!(s.code(), Code::PermissionDenied | Code::Unauthenticated) && !common::is_crash(s.code())
        }
        _ => false,
    };
    if ok { Ok(()) } else { Err(format!("{} → {path}: wanted {want:?}, got {result:?}", c.name)) }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_credential_gets_exactly_its_answer_from_every_method_of_every_server() {
    let t = TestStack::start(|a| a.no_robot = true).await;
    let sec = t.security().clone();
    let pki = &sec.pki;

    // Every credential kind the project issues (`vlnav up`'s PKI, and the
    // per-component certificates of `vlnav credentials k8s`).
    let mut creds = Vec::new();
    let cert = |name: &str, cert: PathBuf, key: PathBuf, identity: String, token: Option<&str>| Credential {
        name: name.to_string(),
        cert: Some((cert, key)),
        identity: Some(identity),
        token: token.map(str::to_string),
    };
    for robot in ["husky-1", "husky-2"] {
        pki.ensure_robot(robot).unwrap();
        let id = vlnav_runtime::security::robot_identity(robot);
        creds.push(cert(&format!("robot {robot}"), pki.robot_cert(robot), pki.robot_key(robot), id, None));
    }
    let id = vlnav_runtime::security::robot_identity("husky-1");
    creds.push(cert(
        "robot husky-1 with the operator token",
        pki.robot_cert("husky-1"),
        pki.robot_key("husky-1"),
        id,
        Some("operator"),
    ));
    creds.push(cert("gateway", pki.gateway_cert(), pki.gateway_key(), GATEWAY_IDENTITY.into(), None));
    creds.push(cert(
        "gateway with the operator token",
        pki.gateway_cert(),
        pki.gateway_key(),
        GATEWAY_IDENTITY.into(),
        Some("operator"),
    ));
    creds.push(cert("dev server certificate", pki.server_cert(), pki.server_key(), service_identity("server"), None));
    for (_, stage) in STAGES {
        let (c, k) = (t.data.path().join(format!("{stage}.pem")), t.data.path().join(format!("{stage}-key.pem")));
        pki.issue_service(stage, &["localhost".into()], &c, &k).unwrap();
        creds.push(cert(&format!("stage {stage}"), c, k, service_identity(stage), None));
    }
    for (name, token) in [("operator token", Some("operator")), ("viewer token", Some("viewer")), ("nothing", None)] {
        creds.push(Credential { name: name.into(), cert: None, identity: None, token: token.map(str::to_string) });
    }
    let secret = |role: &str| match role {
        "operator" => sec.operator_token.clone(),
        _ => sec.viewer_token.clone(),
    };
    let ca = std::fs::read(pki.ca()).unwrap();

    let fds = prost_types::FileDescriptorSet::decode(vlnav_proto::FILE_DESCRIPTOR_SET).expect("descriptor set");
    let p = t.stack.ports;
    let port_of = |service: &str| match service {
        "MissionService" | "FleetService" => t.stack.gateway_addr.port(),
        "IngressService" => p.ingress,
        "PlannerService" => p.planner,
        "DetectorService" => p.detector,
        "ReidService" => p.reid,
        "SegmenterService" => p.segmenter,
        "SubgoalService" => p.subgoal,
        "LocalPlannerService" => p.local_planner,
        other => panic!("no server known for {other}: add it to this test"),
    };

    let mut failures = Vec::new();
    let mut tally = BTreeMap::<(String, Expect), usize>::new();
    let mut methods = 0;
    for c in &creds {
        let identity = c.cert.as_ref().map(|(cert, key)| (std::fs::read(cert).unwrap(), std::fs::read(key).unwrap()));
        let security = ClientSecurity::new(Some(ClientTls::new(ca.clone(), identity)), c.token.as_deref().map(&secret));
        methods = 0;
        for file in &fds.file {
            for service in &file.service {
                let name = service.name();
                let channel = channel_with(&format!("https://127.0.0.1:{}", port_of(name)), &security).unwrap();
                for method in &service.method {
                    methods += 1;
                    let path = format!("/{}.{}/{}", file.package(), name, method.name());
                    let want = expect(c, name, method.name());
                    let streaming = method.client_streaming() || method.server_streaming();
                    let result = tokio::time::timeout(Duration::from_secs(30), call(channel.clone(), &path, streaming))
                        .await
                        .unwrap_or_else(|_| panic!("{} → {path} hung", c.name));
                    if let Err(e) = check(c, &path, want, &result) {
                        failures.push(e);
                    }
                    *tally.entry((c.name.clone(), want)).or_default() += 1;
                }
            }
        }
    }
    assert!(failures.is_empty(), "{} of the matrix's answers differ:\n{}", failures.len(), failures.join("\n"));
    assert!(methods >= 27, "every method of every server: {methods}");
    // Each kind of answer occurs, so no row of the matrix is vacuous.
    for want in [Expect::Denied, Expect::NoHandshake, Expect::Unauthenticated, Expect::WrongRole, Expect::Through] {
        assert!(tally.keys().any(|(_, w)| *w == want), "no call expected {want:?}");
    }
    // The stages' whole surface: a robot is refused everywhere, the gateway gets through everywhere.
    let stage_methods: usize = fds
        .file
        .iter()
        .flat_map(|f| &f.service)
        .filter(|s| STAGES.iter().any(|(n, _)| *n == s.name()))
        .map(|s| s.method.len())
        .sum();
    assert!(stage_methods >= 19, "{stage_methods}");
    assert_eq!(tally[&("robot husky-1".into(), Expect::Denied)], methods - 1, "everything but Attach");
    assert_eq!(tally[&("gateway".into(), Expect::Through)], stage_methods);
    eprintln!("{} credentials × {methods} methods answered as the matrix says: {tally:?}", creds.len());

    // The health of every stage stays open to a robot's certificate (probes, grpcurl).
    let robot_pair =
        (std::fs::read(pki.robot_cert("husky-2")).unwrap(), std::fs::read(pki.robot_key("husky-2")).unwrap());
    let robot = ClientTls::new(ca, Some(robot_pair));
    for (service, _) in STAGES {
        let ch = channel_with(
            &format!("https://127.0.0.1:{}", port_of(service)),
            &ClientSecurity::new(Some(robot.clone()), None),
        )
        .unwrap();
        let status = tonic_health::pb::health_client::HealthClient::new(ch)
            .check(tonic_health::pb::HealthCheckRequest { service: format!("vlnav.v1.{service}") })
            .await
            .unwrap_or_else(|e| panic!("{service}'s health: {e}"));
        assert_eq!(status.into_inner().status, 1, "{service} SERVING");
    }
    t.stack.shutdown().await.unwrap();
}
