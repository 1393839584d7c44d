//! The command path's defences (docs/security.md), attacked with the real
//! clients: grpcurl without TLS, without a token, with the wrong role, with
//! an expired or revoked token; an edge agent claiming another robot's id or
//! none; an edge agent pointed at a gateway whose certificate another CA
//! signed.

use std::time::Duration;

use vlnav_e2e::{TestStack, grpcurl, grpcurl_with};
use vlnav_proto::v1::{EdgeHello, EdgeMessage, GetMissionRequest, MissionState, edge_message};
use vlnav_runtime::security::DevPki;

fn submit_body(text: &str) -> String {
    serde_json::json!({"robot_id": "husky-1", "text": text}).to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn callers_need_tls_and_a_token_of_the_right_role() {
    let t = TestStack::start(|_| {}).await;
    let addr = t.addr();
    let sec = t.security().clone();
    const SUBMIT: &str = "vlnav.v1.MissionService/SubmitMission";
    const LIST: &str = "vlnav.v1.MissionService/ListMissions";

    // Plaintext is refused, and so is TLS the client cannot verify.
    let e = grpcurl(&["-plaintext", &addr, "list"]).expect_err("plaintext is refused");
    assert!(!e.is_empty());
    let e = grpcurl(&[&addr, "list"]).expect_err("an unverified server is refused by grpcurl");
    assert!(e.contains("certificate"), "{e}");

    // Listing and describing need no token.
    let ca_only = &t.grpcurl_auth("")[..2];
    let listed = grpcurl_with(ca_only, &[&addr, "list"]).expect("list without a token");
    assert!(listed.contains("vlnav.v1.MissionService"), "{listed}");
    grpcurl_with(ca_only, &[&addr, "describe", "vlnav.v1.MissionService"]).expect("describe without a token");

    // No token: Unauthenticated, saying what to send.
    let e = grpcurl_with(ca_only, &["-d", &submit_body("move 1 m ahead"), &addr, SUBMIT]).unwrap_err();
    assert!(e.contains("Unauthenticated") && e.contains("authorization: Bearer"), "{e}");
    let e = grpcurl_with(&t.grpcurl_auth("not-a-token"), &["-d", "{}", &addr, LIST]).unwrap_err();
    assert!(e.contains("Unauthenticated") && e.contains("not known"), "{e}");

    // A viewer may look but not command.
    let viewer = t.grpcurl_auth(&sec.viewer_token);
    let e = grpcurl_with(&viewer, &["-d", &submit_body("move 1 m ahead"), &addr, SUBMIT]).unwrap_err();
    assert!(e.contains("PermissionDenied") && e.contains("operator role"), "{e}");
    grpcurl_with(&viewer, &["-d", "{}", &addr, LIST]).expect("a viewer lists missions");

    // An operator's mission runs, and the store says who asked.
    let op = t.grpcurl_auth(&sec.operator_token);
    let out = grpcurl_with(&op, &["-d", &submit_body("move 1 m ahead"), &addr, SUBMIT]).expect("operator submits");
    let id = serde_json::from_str::<serde_json::Value>(&out).unwrap()["missionId"].as_str().unwrap().to_string();
    let (_, mission) = t.follow(&id, Duration::from_secs(120)).await;
    assert_eq!(mission.state, MissionState::Succeeded as i32, "{}", mission.reason);
    assert_eq!(mission.submitted_by, "local-operator");
    assert_eq!(mission.audit.len(), 1);
    assert_eq!((mission.audit[0].action.as_str(), mission.audit[0].caller.as_str()), ("submit", "local-operator"));
    assert!(mission.audit[0].unix_time > 1.7e9);

    // Tokens are read again when their file changes: an expired one and a
    // revoked one are refused without a restart.
    let file = sec.tokens_file.clone();
    let text = std::fs::read_to_string(&file).unwrap();
    let expired = "expired-token-of-a-contractor";
    let mut rotated: String =
        text.split("[[token]]").filter(|block| !block.contains("local-viewer")).collect::<Vec<_>>().join("[[token]]");
    rotated.push_str(&format!(
        "\n[[token]]\nname = \"contractor\"\nrole = \"operator\"\nsha256 = \"{}\"\nexpires_unix = 1000.0\n",
        vlnav_runtime::security::token_hash(expired)
    ));
    let scoped = "token-of-the-husky-2-operator";
    rotated.push_str(&format!(
        "\n[[token]]\nname = \"husky-2-crew\"\nrole = \"operator\"\nsha256 = \"{}\"\nrobots = [\"husky-2\"]\n",
        vlnav_runtime::security::token_hash(scoped)
    ));
    std::fs::write(&file, rotated).unwrap();
    tokio::time::sleep(Duration::from_millis(1300)).await;
    let e = grpcurl_with(&t.grpcurl_auth(expired), &["-d", "{}", &addr, LIST]).unwrap_err();
    assert!(e.contains("Unauthenticated") && e.contains("expired"), "{e}");
    let e = grpcurl_with(&viewer, &["-d", "{}", &addr, LIST]).unwrap_err();
    assert!(e.contains("Unauthenticated"), "the revoked viewer token is refused: {e}");
    grpcurl_with(&op, &["-d", "{}", &addr, LIST]).expect("the operator token still works");

    // A token scoped to husky-2 neither commands nor sees husky-1.
    let crew = t.grpcurl_auth(scoped);
    let e = grpcurl_with(&crew, &["-d", &submit_body("move 1 m ahead"), &addr, SUBMIT]).unwrap_err();
    assert!(e.contains("PermissionDenied") && e.contains("husky-2-crew"), "{e}");
    let body = serde_json::json!({"mission_id": id}).to_string();
    let e = grpcurl_with(&crew, &["-d", &body, &addr, "vlnav.v1.MissionService/GetMission"]).unwrap_err();
    assert!(e.contains("PermissionDenied"), "{e}");
    let listed = grpcurl_with(&crew, &["-d", "{}", &addr, LIST]).expect("a scoped list");
    assert!(!listed.contains(&id), "another robot's mission is not listed: {listed}");
    let still = t.missions().await.get_mission(GetMissionRequest { mission_id: id }).await;
    assert!(still.is_ok());
    t.stack.shutdown().await.unwrap();
}

fn hello(robot: &str) -> EdgeHello {
    EdgeHello { robot_id: robot.into(), driver: "test".into(), ..Default::default() }
}

/// Attaches with `client` as `robot` and returns the refusal.
async fn attach_refused(
    mut client: vlnav_proto::v1::fleet_service_client::FleetServiceClient<vlnav_runtime::client::TracedChannel>,
    robot: &str,
) -> tonic::Status {
    let msgs = vec![EdgeMessage { kind: Some(edge_message::Kind::Hello(hello(robot))) }];
    match client.attach(tokio_stream::iter(msgs)).await {
        Err(s) => s,
        Ok(_) => panic!("attaching as {robot} was accepted"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_robot_attaches_only_as_itself_and_only_to_a_gateway_it_verified() {
    let t = TestStack::start(|a| a.no_robot = true).await;

    // Robot husky-2's certificate claiming husky-3.
    let s = attach_refused(t.fleet_as_robot("husky-2"), "husky-3").await;
    assert_eq!(s.code(), tonic::Code::PermissionDenied, "{s:?}");
    assert!(s.message().contains("husky-2") && s.message().contains("husky-3"), "{}", s.message());

    // No certificate at all (a token does not make a robot).
    let s = attach_refused(t.fleet(), "husky-3").await;
    assert_eq!(s.code(), tonic::Code::PermissionDenied, "{s:?}");
    assert!(s.message().contains("spiffe://vlnav/robot/husky-3"), "{}", s.message());

    // The real edge agent with its own certificate attaches.
    let sec = t.security();
    let opts = vlnav_edge_agent::EdgeOptions {
        gateway: t.uri(),
        robot_id: "husky-3".into(),
        tls: sec.robot("husky-3").unwrap(),
        ..Default::default()
    };
    vlnav_edge_agent::agent::Link::connect(&opts, hello("husky-3")).await.expect("husky-3 attaches as itself");

    // A gateway with a certificate from another CA: the agent refuses it.
    let other_dir = tempfile::tempdir().unwrap();
    let other = DevPki::ensure(other_dir.path(), &[]).unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let impostor = format!("https://{}", listener.local_addr().unwrap());
    let cfg =
        vlnav_runtime::ServerConfig { tls: other.server_args(), client_cert_optional: true, ..Default::default() };
    let token = vlnav_runtime::CancellationToken::new();
    let server = tokio::spawn({
        let token = token.clone();
        async move { vlnav_runtime::serve(&cfg, listener, vlnav_runtime::ServiceSet::new(), token).await }
    });
    let opts = vlnav_edge_agent::EdgeOptions { gateway: impostor, ..opts };
    let e = vlnav_edge_agent::agent::Link::connect(&opts, hello("husky-3")).await.err().expect("refused");
    let chain = format!("{e:#}");
    assert!(chain.contains("UnknownIssuer") || chain.contains("certificate"), "{chain}");

    // A CA given but a plaintext gateway address: refused before connecting.
    let plain = vlnav_edge_agent::EdgeOptions { gateway: t.uri().replace("https://", "http://"), ..opts };
    let e = vlnav_edge_agent::agent::Link::connect(&plain, hello("husky-3")).await.err().expect("refused");
    assert!(e.to_string().contains("not https://"), "{e}");

    token.cancel();
    server.await.unwrap().unwrap();
    t.stack.shutdown().await.unwrap();
}
