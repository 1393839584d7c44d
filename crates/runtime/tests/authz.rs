//! The caller policy over real connections (`vlnav_runtime::authz`): a
//! stage served by `serve` over mutual TLS answers the gateway's certificate
//! and refuses a robot's, another service's and a certificate-less caller's
//! with PERMISSION_DENIED naming them; health stays open; plaintext is not
//! checked; TLS without a client CA is refused at start.

use tonic::{Code, Status};
use vlnav_proto::v1::detector_service_client::DetectorServiceClient;
use vlnav_proto::v1::detector_service_server::DetectorServiceServer;
use vlnav_proto::v1::{DetectRequest, GetModelInfoRequest};
use vlnav_runtime::authz::{CallerPolicy, Callers, Methods};
use vlnav_runtime::client::{TracedChannel, channel_with};
use vlnav_runtime::security::{ClientSecurity, ClientTls, DevPki};
use vlnav_runtime::server::{ServerConfig, ServiceSet};
use vlnav_runtime::testing::{StubDetector, TestServer, start};

fn detector(policy: CallerPolicy) -> ServiceSet {
    ServiceSet::new().add("detect", DetectorServiceServer::new(StubDetector)).callers(policy)
}

fn read(p: std::path::PathBuf) -> Vec<u8> {
    std::fs::read(p).unwrap()
}

/// A client of `server` over TLS, presenting `identity` (certificate, key) if given.
fn client(
    pki: &DevPki,
    server: &TestServer,
    identity: Option<(Vec<u8>, Vec<u8>)>,
) -> DetectorServiceClient<TracedChannel> {
    let tls = ClientTls::new(read(pki.ca()), identity);
    let uri = format!("https://{}", server.addr());
    DetectorServiceClient::new(channel_with(&uri, &ClientSecurity::new(Some(tls), None)).unwrap())
}

async fn model_info(c: &mut DetectorServiceClient<TracedChannel>) -> Result<String, Status> {
    c.get_model_info(GetModelInfoRequest {}).await.map(|r| r.into_inner().model)
}

async fn health(pki: &DevPki, server: &TestServer, identity: Option<(Vec<u8>, Vec<u8>)>) -> i32 {
    let tls = ClientTls::new(read(pki.ca()), identity);
    let uri = format!("https://{}", server.addr());
    let ch = channel_with(&uri, &ClientSecurity::new(Some(tls), None)).unwrap();
    tonic_health::pb::health_client::HealthClient::new(ch)
        .check(tonic_health::pb::HealthCheckRequest { service: "vlnav.v1.DetectorService".into() })
        .await
        .expect("health is open to every certificate the CA signed")
        .into_inner()
        .status
}

#[tokio::test]
async fn a_stage_over_mutual_tls_answers_only_the_gateway() {
    let dir = tempfile::tempdir().unwrap();
    let pki = DevPki::ensure(dir.path(), &["husky-1"]).unwrap();
    let (planner_cert, planner_key) = (dir.path().join("planner.pem"), dir.path().join("planner-key.pem"));
    pki.issue_service("planner", &["localhost".into()], &planner_cert, &planner_key).unwrap();
    let gateway = Some((read(pki.gateway_cert()), read(pki.gateway_key())));
    let robot = Some((read(pki.robot_cert("husky-1")), read(pki.robot_key("husky-1"))));
    let planner = Some((read(planner_cert), read(planner_key)));

    let cfg = ServerConfig { tls: pki.server_args(), ..Default::default() };
    let server = start(&cfg, detector(CallerPolicy::stages())).await.unwrap();

    assert_eq!(model_info(&mut client(&pki, &server, gateway.clone())).await.unwrap(), "stub");
    let e = client(&pki, &server, gateway.clone()).detect(DetectRequest::default()).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "the gateway reaches the handler: {e:?}");

    let mut as_robot = client(&pki, &server, robot.clone());
    let e = model_info(&mut as_robot).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    assert_eq!(
        e.message(),
        "spiffe://vlnav/robot/husky-1 may not call /vlnav.v1.DetectorService/GetModelInfo; \
         stages answer only spiffe://vlnav/service/gateway"
    );
    let e = as_robot.detect(DetectRequest::default()).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "refused before the handler looks at the request: {e:?}");

    let e = model_info(&mut client(&pki, &server, planner.clone())).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    assert!(e.message().starts_with("spiffe://vlnav/service/planner may not call"), "{}", e.message());

    // Health stays open to every certificate the CA signed.
    for who in [gateway.clone(), robot.clone(), planner.clone()] {
        assert_eq!(health(&pki, &server, who).await, 1, "SERVING");
    }
    server.stop().await.unwrap();

    // Where certificates are optional, a caller without one is no gateway.
    let optional = ServerConfig { client_cert_optional: true, ..cfg.clone() };
    let server = start(&optional, detector(CallerPolicy::stages())).await.unwrap();
    let e = model_info(&mut client(&pki, &server, None)).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    assert!(e.message().starts_with("a caller without a client certificate may not call"), "{}", e.message());
    assert_eq!(model_info(&mut client(&pki, &server, gateway.clone())).await.unwrap(), "stub");
    assert_eq!(health(&pki, &server, None).await, 1);
    server.stop().await.unwrap();

    // A policy that admits callers without a certificate, and robots.
    let people = CallerPolicy::new().allow(
        Methods::service("vlnav.v1.DetectorService"),
        [Callers::Uncertified, Callers::robots()],
        "",
    );
    let server = start(&optional, detector(people)).await.unwrap();
    assert_eq!(model_info(&mut client(&pki, &server, None)).await.unwrap(), "stub");
    assert_eq!(model_info(&mut client(&pki, &server, robot.clone())).await.unwrap(), "stub");
    let e = model_info(&mut client(&pki, &server, gateway.clone())).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    server.stop().await.unwrap();

    // A set that names no policy answers nobody but health over TLS.
    let server = start(&cfg, ServiceSet::new().add("detect", DetectorServiceServer::new(StubDetector))).await.unwrap();
    let e = model_info(&mut client(&pki, &server, gateway.clone())).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    assert_eq!(health(&pki, &server, gateway.clone()).await, 1);
    server.stop().await.unwrap();
}

#[tokio::test]
async fn plaintext_is_not_checked_and_tls_without_a_client_ca_does_not_start() {
    let server = start(&ServerConfig::default(), detector(CallerPolicy::stages())).await.unwrap();
    let mut c = DetectorServiceClient::new(server.connect().await.unwrap());
    let info = c.get_model_info(GetModelInfoRequest {}).await.expect("plaintext carries no identity to check");
    assert_eq!(info.into_inner().model, "stub");
    server.stop().await.unwrap();

    let dir = tempfile::tempdir().unwrap();
    let pki = DevPki::ensure(dir.path(), &[]).unwrap();
    let mut tls = pki.server_args();
    tls.tls_client_ca = None;
    // Without a client CA a revocation list is refused first, on its own
    // (crates/runtime/src/security.rs); here the policy is what is checked.
    tls.tls_revoked = None;
    let cfg = ServerConfig { tls, ..Default::default() };
    let server = start(&cfg, detector(CallerPolicy::stages())).await.unwrap();
    let e = server.stop().await.unwrap_err().to_string();
    assert!(e.contains("--tls-client-ca") && e.contains("vlnav.v1.DetectorService"), "{e}");
}
