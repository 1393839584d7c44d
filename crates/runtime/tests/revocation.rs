//! Revocation and renewal without restarts over real mutual-TLS connections
//! (docs/security.md, "Certificates"): a server served by `serve` reads its
//! revocation list and its own certificate again when their files change;
//! a revoked caller's running stream ends with PERMISSION_DENIED naming the
//! revocation, its new handshakes are refused, other callers go on; a
//! renewed server certificate is presented to the next connection while
//! the running streams continue; a client presents its renewed certificate
//! at its next connection.

use std::path::Path;
use std::time::Duration;

use tokio::sync::mpsc;
use tokio_stream::StreamExt as _;
use tonic::{Code, Status, Streaming};
use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
use tonic_reflection::pb::v1::{ServerReflectionRequest, ServerReflectionResponse};
use vlnav_proto::v1::GetModelInfoRequest;
use vlnav_proto::v1::detector_service_client::DetectorServiceClient;
use vlnav_proto::v1::detector_service_server::DetectorServiceServer;
use vlnav_runtime::CallerPolicy;
use vlnav_runtime::client::{TracedChannel, channel_with};
use vlnav_runtime::revocation::{CertificateId, RevocationList, Revoked};
use vlnav_runtime::security::{ClientSecurity, ClientTls, DevPki, robot_identity};
use vlnav_runtime::server::{ServerConfig, ServiceSet};
use vlnav_runtime::testing::{StubDetector, TestServer, start};
use vlnav_runtime::tls::{RELOAD_INTERVAL, ServerTls};

/// A stage (only the gateway may call it) with health and reflection, which
/// every certificate may use: reflection is the bidirectional stream here.
async fn stage(pki: &DevPki) -> TestServer {
    let cfg = ServerConfig { tls: pki.server_args(), ..Default::default() };
    let set = ServiceSet::new().add("detect", DetectorServiceServer::new(StubDetector)).callers(CallerPolicy::stages());
    start(&cfg, set).await.unwrap()
}

fn files(pki: &DevPki, robot: &str) -> ClientTls {
    ClientTls::from_files(std::fs::read(pki.ca()).unwrap(), &pki.robot_cert(robot), &pki.robot_key(robot)).unwrap()
}

fn gateway(pki: &DevPki) -> ClientTls {
    ClientTls::from_files(std::fs::read(pki.ca()).unwrap(), &pki.gateway_cert(), &pki.gateway_key()).unwrap()
}

fn channel(server: &TestServer, tls: ClientTls) -> TracedChannel {
    channel_with(&format!("https://{}", server.addr()), &ClientSecurity::new(Some(tls), None)).unwrap()
}

/// A reflection stream: a request goes up, its answer comes down.
struct Reflection {
    tx: mpsc::Sender<ServerReflectionRequest>,
    rx: Streaming<ServerReflectionResponse>,
}

impl Reflection {
    async fn open(ch: TracedChannel) -> Result<Self, Status> {
        let (tx, rx) = mpsc::channel(4);
        let rx = ServerReflectionClient::new(ch)
            .server_reflection_info(tokio_stream::wrappers::ReceiverStream::new(rx))
            .await?
            .into_inner();
        Ok(Self { tx, rx })
    }

    /// Asks for the list of services and waits for the answer.
    async fn ask(&mut self) -> Result<usize, Status> {
        let req = ServerReflectionRequest {
            host: String::new(),
            message_request: Some(MessageRequest::ListServices(String::new())),
        };
        let _ = self.tx.send(req).await;
        match tokio::time::timeout(Duration::from_secs(5), self.rx.message()).await {
            Err(_) => Err(Status::deadline_exceeded("no answer on the stream within 5 s")),
            Ok(Ok(Some(resp))) => Ok(format!("{resp:?}").matches("name:").count()),
            Ok(Ok(None)) => Err(Status::unknown("the stream ended without a status")),
            Ok(Err(s)) => Err(s),
        }
    }

    /// Waits for the stream to end with a status, without asking anything.
    async fn ended(&mut self, limit: Duration) -> Status {
        match tokio::time::timeout(limit, self.rx.message()).await {
            Err(_) => panic!("the stream was not ended within {limit:?}"),
            Ok(Ok(m)) => panic!("the stream went on: {m:?}"),
            Ok(Err(s)) => s,
        }
    }
}

/// Why the server ends a new TLS connection presenting `tls`'s certificate.
/// In TLS 1.3 the server verifies the client's certificate after the
/// client's handshake is done: its alert is what the client reads next.
async fn refusal(tls: &ClientTls, server: &TestServer) -> String {
    use tokio::io::AsyncReadExt as _;
    let mut conn = tls.connector(None).unwrap().connect("127.0.0.1", server.addr().port()).await.unwrap();
    match conn.read(&mut [0u8; 64]).await {
        Ok(n) => panic!("the server let the connection through ({n} bytes read)"),
        Err(e) => e.to_string(),
    }
}

fn revoke(pki: &DevPki, entry: Revoked) {
    let mut list = RevocationList::load(&pki.revoked()).unwrap();
    list.add(entry);
    list.save(&pki.revoked()).unwrap();
}

/// Long enough for a server to have read a changed file.
const PICKED_UP: Duration = Duration::from_millis(2 * RELOAD_INTERVAL.as_millis() as u64 + 500);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_revoked_robots_stream_is_ended_with_the_reason_and_its_new_handshakes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let pki = DevPki::ensure(dir.path(), &["husky-1", "husky-2"]).unwrap();
    let server = stage(&pki).await;
    let mut husky1 = Reflection::open(channel(&server, files(&pki, "husky-1"))).await.unwrap();
    let mut husky2 = Reflection::open(channel(&server, files(&pki, "husky-2"))).await.unwrap();
    assert!(husky1.ask().await.unwrap() > 0);
    assert!(husky2.ask().await.unwrap() > 0);
    let existing = channel(&server, files(&pki, "husky-1"));
    let health = |ch: TracedChannel| async move {
        tonic_health::pb::health_client::HealthClient::new(ch)
            .check(tonic_health::pb::HealthCheckRequest { service: String::new() })
            .await
    };
    health(existing.clone()).await.expect("husky-1 is not revoked yet");

    revoke(
        &pki,
        Revoked { identity: Some(robot_identity("husky-1")), reason: "lost in the field".into(), ..Default::default() },
    );

    // The running stream ends, saying why.
    let s = husky1.ended(PICKED_UP).await;
    assert_eq!(s.code(), Code::PermissionDenied, "{s:?}");
    assert!(
        s.message().contains("identity spiffe://vlnav/robot/husky-1 is revoked (lost in the field)"),
        "{}",
        s.message()
    );
    // Another call over the connection it already had: refused the same way.
    let s = health(existing).await.unwrap_err();
    assert_eq!(s.code(), Code::PermissionDenied, "{s:?}");
    assert!(s.message().contains("revoked"), "{}", s.message());
    // A new connection: refused at the handshake.
    assert!(health(channel(&server, files(&pki, "husky-1"))).await.is_err());
    assert_eq!(refusal(&files(&pki, "husky-1"), &server).await, "received fatal alert: CertificateRevoked");
    // Another robot goes on, on its running stream and on new connections.
    assert!(husky2.ask().await.unwrap() > 0);
    health(channel(&server, files(&pki, "husky-2"))).await.unwrap();

    // A list that does not parse is not taken: the previous one stays.
    std::fs::write(pki.revoked(), "[[revoked]]\nidentity = \"husky-2\"\n").unwrap();
    tokio::time::sleep(PICKED_UP).await;
    assert!(husky2.ask().await.unwrap() > 0, "a bad list revokes nobody new");
    assert!(health(channel(&server, files(&pki, "husky-1"))).await.is_err(), "and un-revokes nobody");

    // Emptied: husky-1 is answered again (without a server restart).
    std::fs::write(pki.revoked(), "").unwrap();
    tokio::time::sleep(PICKED_UP).await;
    health(channel(&server, files(&pki, "husky-1"))).await.expect("no longer revoked");
    // Graceful shutdown waits for open streams.
    drop((husky1, husky2));
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_revoked_component_certificate_is_refused_and_its_successor_answered() {
    let dir = tempfile::tempdir().unwrap();
    let pki = DevPki::ensure(dir.path(), &[]).unwrap();
    let server = stage(&pki).await;
    let mut client = DetectorServiceClient::new(channel(&server, gateway(&pki)));
    assert_eq!(client.get_model_info(GetModelInfoRequest {}).await.unwrap().into_inner().model, "stub");

    // Revoke the gateway's certificate by its serial (a leaked key).
    let old = CertificateId::of_pem_file(&pki.gateway_cert()).unwrap();
    revoke(&pki, Revoked { serial: Some(old.serial.clone()), reason: "key leaked".into(), ..Default::default() });
    tokio::time::sleep(PICKED_UP).await;
    let s = client.get_model_info(GetModelInfoRequest {}).await.unwrap_err();
    assert_eq!(s.code(), Code::PermissionDenied, "{s:?}");
    assert!(
        s.message().contains(&format!("(serial {}): certificate is revoked (key leaked)", old.serial)),
        "{}",
        s.message()
    );
    assert!(
        DetectorServiceClient::new(channel(&server, gateway(&pki)))
            .get_model_info(GetModelInfoRequest {})
            .await
            .is_err()
    );
    assert_eq!(refusal(&gateway(&pki), &server).await, "received fatal alert: CertificateRevoked");

    // A new certificate for the same identity is answered.
    std::fs::remove_file(pki.gateway_cert()).unwrap();
    let pki = DevPki::ensure(dir.path(), &[]).unwrap();
    assert_ne!(CertificateId::of_pem_file(&pki.gateway_cert()).unwrap().serial, old.serial);
    let mut renewed = DetectorServiceClient::new(channel(&server, gateway(&pki)));
    assert_eq!(renewed.get_model_info(GetModelInfoRequest {}).await.unwrap().into_inner().model, "stub");

    // Revoking the identity refuses the successor too.
    revoke(&pki, Revoked { identity: Some(vlnav_runtime::security::GATEWAY_IDENTITY.into()), ..Default::default() });
    tokio::time::sleep(PICKED_UP).await;
    let s = renewed.get_model_info(GetModelInfoRequest {}).await.unwrap_err();
    assert_eq!(s.code(), Code::PermissionDenied, "{s:?}");
    assert!(s.message().contains("identity spiffe://vlnav/service/gateway is revoked"), "{}", s.message());
    server.stop().await.unwrap();
}

/// The serial of the certificate a server presents to a new connection.
async fn presented_serial(pki: &DevPki, server: &TestServer) -> String {
    let tls = gateway(pki).connector(None).unwrap();
    let conn = tls.connect("127.0.0.1", server.addr().port()).await.unwrap();
    let leaf = conn.get_ref().1.peer_certificates().unwrap()[0].clone();
    CertificateId::of(leaf.as_ref()).serial
}

fn serial_of(path: &Path) -> String {
    CertificateId::of_pem_file(path).unwrap().serial
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_renewed_server_certificate_is_presented_to_new_connections_while_streams_run_on() {
    let dir = tempfile::tempdir().unwrap();
    let pki = DevPki::ensure(dir.path(), &["husky-1"]).unwrap();
    let server = stage(&pki).await;
    let old = serial_of(&pki.server_cert());
    assert_eq!(presented_serial(&pki, &server).await, old);
    let mut running = Reflection::open(channel(&server, files(&pki, "husky-1"))).await.unwrap();
    assert!(running.ask().await.unwrap() > 0);
    let mut detector = DetectorServiceClient::new(channel(&server, gateway(&pki)));
    detector.get_model_info(GetModelInfoRequest {}).await.unwrap();

    // A renewal as cert-manager does it: new key, new certificate, same names.
    let names = ["localhost".to_string(), "127.0.0.1".to_string()];
    pki.issue_service("server", &names, &pki.server_cert(), &pki.server_key()).unwrap();
    let new = serial_of(&pki.server_cert());
    assert_ne!(new, old);
    tokio::time::sleep(PICKED_UP).await;

    assert_eq!(presented_serial(&pki, &server).await, new, "a new connection sees the renewed certificate");
    assert!(running.ask().await.unwrap() > 0, "the stream opened before the renewal goes on");
    detector.get_model_info(GetModelInfoRequest {}).await.expect("so does the connection opened before");
    let mut fresh = DetectorServiceClient::new(channel(&server, gateway(&pki)));
    fresh.get_model_info(GetModelInfoRequest {}).await.expect("a new client verifies the renewed certificate");

    // A renewal half written (a key that is not the certificate's) is not taken.
    let other = DevPki::ensure(&dir.path().join("other"), &[]).unwrap();
    std::fs::copy(other.server_key(), pki.server_key()).unwrap();
    tokio::time::sleep(PICKED_UP).await;
    assert_eq!(presented_serial(&pki, &server).await, new, "the pair in use stays");
    drop(running);
    server.stop().await.unwrap();
}

/// The serial of the client certificate the server saw on a new connection.
async fn presented(
    connector: &vlnav_runtime::tls::ClientConnector,
    port: u16,
    accepted: &mut (impl tokio_stream::Stream<Item = std::io::Result<vlnav_runtime::tls::ServerStream>> + Unpin),
) -> String {
    let (client, server) = tokio::join!(connector.connect("127.0.0.1", port), accepted.next());
    client.unwrap();
    let server = server.unwrap().unwrap();
    CertificateId::of(server.get_ref().1.peer_certificates().unwrap()[0].as_ref()).serial
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_presents_its_renewed_certificate_at_its_next_connection() {
    let dir = tempfile::tempdir().unwrap();
    let pki = DevPki::ensure(dir.path(), &["husky-1"]).unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    let tls = ServerTls::load(&pki.server_cert(), &pki.server_key(), Some(&pki.ca()), None, false).unwrap();
    let stop = vlnav_runtime::CancellationToken::new();
    let mut accepted = Box::pin(tls.incoming(listener, stop.clone()));
    // One connector for the client's whole life, as a channel keeps it.
    let connector = files(&pki, "husky-1").connector(Some("localhost")).unwrap();
    let old = serial_of(&pki.robot_cert("husky-1"));
    assert_eq!(presented(&connector, port, &mut accepted).await, old);
    std::fs::remove_file(pki.robot_cert("husky-1")).unwrap();
    pki.ensure_robot("husky-1").unwrap();
    let new = serial_of(&pki.robot_cert("husky-1"));
    assert_ne!(new, old);
    assert_eq!(
        presented(&connector, port, &mut accepted).await,
        new,
        "the renewed certificate, read at the next connection"
    );
    // Files that do not load keep the certificate in use.
    std::fs::write(pki.robot_cert("husky-1"), "not PEM").unwrap();
    assert_eq!(presented(&connector, port, &mut accepted).await, new);
    stop.cancel();
}
