//! `vlnav credentials k8s`: the certificates and tokens a Kubernetes
//! deployment reads from Secrets (k8s/base, docs/security.md), written as a
//! kustomization to apply before the stack. One CA signs a certificate per
//! component, valid for the names of that component's Services; the
//! gateway's token file holds only hashes.
//!
//! `vlnav credentials revoke`: adds robots, components or single
//! certificates to the revocation list beside the CA, which servers read
//! again within a second (`vlnav_runtime::revocation`).
//!
//! `vlnav credentials robot`: one more robot's certificate from an existing
//! CA (`vlnav up`'s or `vlnav credentials k8s`'), and the `vlnav-edge` flags
//! that use it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use base64::Engine as _;
use vlnav_runtime::security::DevPki;

#[derive(clap::Args, Clone, Debug)]
pub struct K8sCredentialsArgs {
    /// Directory to write into (created). A CA already there is reused, so
    /// running again renews every component certificate under the same CA;
    /// tokens already there are kept.
    #[arg(long, default_value = ".vlnav/k8s-credentials")]
    pub out: PathBuf,
    /// The namespace the stack runs in (k8s/base uses `vlnav`).
    #[arg(long, default_value = "vlnav")]
    pub namespace: String,
    /// A name or address clients outside the cluster reach the gateway by
    /// (its LoadBalancer's DNS name or IP); repeatable. `localhost` and
    /// 127.0.0.1 are always included for `kubectl port-forward`.
    #[arg(long = "gateway-name")]
    pub gateway_names: Vec<String>,
    /// A robot to issue an edge-agent certificate for; repeatable.
    #[arg(long = "robot")]
    pub robots: Vec<String>,
}

#[derive(clap::Args, Clone, Debug, Default)]
pub struct RevokeArgs {
    /// Refuse every certificate naming this robot (spiffe://vlnav/robot/<ID>),
    /// issued before or after; repeatable.
    #[arg(long = "robot", value_name = "ID")]
    pub robots: Vec<String>,
    /// Refuse every certificate naming this component
    /// (spiffe://vlnav/service/<NAME>: gateway, planner, ...); repeatable.
    #[arg(long = "service", value_name = "NAME")]
    pub services: Vec<String>,
    /// Refuse only this certificate (a PEM file), by its serial number: a
    /// leaked key, while a new certificate for the same identity is answered;
    /// repeatable.
    #[arg(long = "cert", value_name = "FILE")]
    pub certs: Vec<PathBuf>,
    /// Why, shown in refusals and in the servers' logs.
    #[arg(long, default_value = "")]
    pub reason: String,
    /// The credentials directory holding the CA: `.vlnav/security` of `vlnav
    /// up`, or the --out of `vlnav credentials k8s`. The list is written to
    /// DIR/revoked.toml.
    #[arg(long, default_value = ".vlnav/security")]
    pub dir: PathBuf,
}

#[derive(clap::Args, Clone, Debug)]
pub struct RobotCredentialsArgs {
    /// The robot's id: its certificate names spiffe://vlnav/robot/<ID>, the
    /// identity the gateway admits for `vlnav-edge --robot-id ID`.
    #[arg(long, value_name = "ID")]
    pub id: String,
    /// The directory of the CA to issue from (`ca.pem`, `ca-key.pem`):
    /// `.vlnav/security` of `vlnav up`, or the --out of `vlnav credentials
    /// k8s`. Nothing else in it is read or written.
    #[arg(long, value_name = "DIR", default_value = ".vlnav/security")]
    pub ca_dir: PathBuf,
    /// Where to write robot-<ID>.pem, robot-<ID>-key.pem and a copy of
    /// ca.pem (created): the directory to copy to the robot's computer.
    /// Default: the CA's directory, where only the robot's two files are
    /// written. A new certificate and key each time; an older one stays
    /// valid until it expires or is revoked.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// The gateway's address as the robot dials it (`https://HOST:PORT`),
    /// for the printed command; HOST is checked against the gateway's
    /// certificate in the CA's directory when there is one.
    #[arg(long, value_name = "URL")]
    pub gateway: Option<String>,
}

/// The files of one robot's credentials, as [`issue_robot`] wrote them.
#[derive(Clone, Debug)]
pub struct RobotCredentials {
    pub ca: PathBuf,
    pub cert: PathBuf,
    pub key: PathBuf,
}

/// Issues robot `args.id`'s certificate from the CA in `args.ca_dir`; returns
/// the files and what to tell people: where they are, the `vlnav-edge`
/// flags, and a warning when the gateway's certificate does not name the
/// host the robot dials.
pub fn issue_robot(args: &RobotCredentialsArgs) -> anyhow::Result<(RobotCredentials, String)> {
    use vlnav_runtime::security::valid_robot_id;
    if !valid_robot_id(&args.id) {
        anyhow::bail!("--id {:?}: a robot id is 1–64 letters, digits, '-', '_' or '.'", args.id);
    }
    let gateway = args.gateway.clone().unwrap_or_else(|| "https://$GATEWAY_HOST:50051".into());
    let host = gateway_host(&gateway)?;
    let pki = DevPki::open_ca(&args.ca_dir).with_context(|| {
        format!(
            "--ca-dir {}: give the directory of an existing CA, `.vlnav/security` of `vlnav up` (made on its first start) or the --out of `vlnav credentials k8s`",
            args.ca_dir.display()
        )
    })?;
    let out = args.out.clone().unwrap_or_else(|| args.ca_dir.clone());
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let same_dir = std::fs::canonicalize(&out)? == std::fs::canonicalize(&args.ca_dir)?;
    if !same_dir && out.join("ca-key.pem").exists() {
        anyhow::bail!(
            "--out {} holds another CA (ca-key.pem): give an empty or new directory for the robot's files",
            out.display()
        );
    }
    let files = RobotCredentials {
        ca: if same_dir { pki.ca() } else { out.join("ca.pem") },
        cert: out.join(format!("robot-{}.pem", args.id)),
        key: out.join(format!("robot-{}-key.pem", args.id)),
    };
    pki.issue_robot(&args.id, &files.cert, &files.key)?;
    if !same_dir {
        std::fs::copy(pki.ca(), &files.ca).with_context(|| format!("cannot write {}", files.ca.display()))?;
    }
    let mut report = format!(
        "issued robot {id}'s certificate (spiffe://vlnav/robot/{id}, valid {days} days) from the CA in {ca_dir}:\n  \
         {ca}, {cert}, {key} (the key: owner-only, for the robot's computer alone)\n\
         on the robot's computer, with these files:\n  \
         vlnav-edge --robot-id {id} --gateway {gateway} \\\n    \
         --tls-ca {ca} --tls-client-cert {cert} --tls-client-key {key} \\\n    \
         --driver ros2 --ros-namespace <namespace>    (ROS 1: --driver ros1)",
        id = args.id,
        days = vlnav_runtime::security::DEV_CERT_DAYS,
        ca_dir = args.ca_dir.display(),
        ca = files.ca.display(),
        cert = files.cert.display(),
        key = files.key.display(),
    );
    if let Some(host) = host {
        for gw_cert in [pki.server_cert(), args.ca_dir.join("components/gateway.pem")] {
            let Some(der) = std::fs::read(&gw_cert).ok().and_then(|p| vlnav_runtime::security::pem_to_der(&p)) else {
                continue;
            };
            let names = vlnav_runtime::security::server_names(&der);
            if !names.iter().any(|n| vlnav_runtime::security::same_server_name(n, &host)) {
                let _ = write!(
                    report,
                    "\nwarning: the gateway's certificate {} names {} but not {host}, so the robot will refuse it: \
                     start the gateway with `vlnav up --gateway-name {host}` (a cluster: `vlnav credentials k8s --gateway-name {host}`)",
                    gw_cert.display(),
                    names.join(", ")
                );
            }
        }
    }
    Ok((files, report))
}

/// The host of a gateway address `https://HOST[:PORT]`, `None` for a
/// placeholder (`$GATEWAY_HOST`); an address without `https://` is refused.
fn gateway_host(gateway: &str) -> anyhow::Result<Option<String>> {
    let Some(rest) = gateway.strip_prefix("https://") else {
        anyhow::bail!(
            "--gateway {gateway:?}: give it as https://HOST:PORT; the gateway serves TLS and the edge agent refuses anything else once it has a CA"
        );
    };
    let authority = rest.split('/').next().unwrap_or_default();
    let host = match authority.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or_default(),
        None => authority.rsplit_once(':').map_or(authority, |(h, _)| h),
    };
    if host.starts_with('$') {
        return Ok(None);
    }
    vlnav_runtime::security::check_server_name(host).with_context(|| format!("--gateway {gateway:?}"))?;
    Ok(Some(host.to_string()))
}

/// Adds what `args` names to the revocation list; returns what was done, for
/// people.
pub fn revoke(args: &RevokeArgs) -> anyhow::Result<String> {
    use vlnav_runtime::revocation::{CertificateId, RevocationList, Revoked};
    use vlnav_runtime::security::{robot_identity, service_identity, valid_robot_id};
    if args.robots.is_empty() && args.services.is_empty() && args.certs.is_empty() {
        anyhow::bail!("name what to revoke: --robot ID, --service NAME or --cert FILE");
    }
    if !args.dir.join("ca.pem").exists() {
        anyhow::bail!(
            "{} holds no ca.pem: give --dir, the directory of the CA whose certificates to revoke",
            args.dir.display()
        );
    }
    let mut entries = Vec::new();
    for id in &args.robots {
        if !valid_robot_id(id) {
            anyhow::bail!("--robot {id:?}: a robot id is 1–64 letters, digits, '-', '_' or '.'");
        }
        entries.push((robot_identity(id), Revoked { identity: Some(robot_identity(id)), ..Default::default() }));
    }
    for name in &args.services {
        if !valid_robot_id(name) {
            anyhow::bail!("--service {name:?}: a component name is 1–64 letters, digits, '-', '_' or '.'");
        }
        let id = service_identity(name);
        entries.push((id.clone(), Revoked { identity: Some(id), ..Default::default() }));
    }
    for cert in &args.certs {
        let c = CertificateId::of_pem_file(cert)?;
        entries.push((c.to_string(), Revoked { serial: Some(c.serial.clone()), ..Default::default() }));
    }
    let path = args.dir.join(vlnav_runtime::security::REVOCATION_FILE);
    let mut list = RevocationList::load(&path)?;
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).ok();
    let mut report = String::new();
    for (what, mut entry) in entries {
        entry.reason = args.reason.clone();
        entry.revoked_unix = now;
        let added = list.add(entry);
        let _ = writeln!(report, "{} {what}", if added { "revoked" } else { "already revoked:" });
    }
    list.save(&path)?;
    let _ = write!(
        report,
        "{} lists {} revocations; servers given it (--tls-revoked; `vlnav up` reads it by itself) refuse \
         them within a second and end their running calls",
        path.display(),
        list.entries.len()
    );
    Ok(report)
}

/// Each component with a certificate, and the Services it answers as
/// (k8s/base): a client verifies the Service name it dialled, so a scaled
/// stage's certificate names its headless `-replicas` Service too.
pub const K8S_COMPONENTS: &[(&str, &[&str])] = &[
    ("gateway", &["gateway"]),
    ("ingress", &["ingress", "ingress-replicas"]),
    ("planner", &["planner", "planner-replicas"]),
    ("detector", &["detector", "detector-replicas"]),
    ("reid", &["reid"]),
    ("segmenter", &["segmenter", "segmenter-replicas"]),
    ("subgoal", &["subgoal"]),
    ("local-planner", &["local-planner"]),
    ("otel-collector", &["otel-collector"]),
    ("jaeger", &["jaeger"]),
];

/// The Secret holding `component`'s certificate (type kubernetes.io/tls with
/// `ca.crt`, the keys cert-manager writes too).
pub fn tls_secret_name(component: &str) -> String {
    format!("vlnav-{component}-tls")
}

/// The Secret holding the gateway's token file (`tokens.toml`).
pub const TOKENS_SECRET: &str = "vlnav-gateway-tokens";

/// The DNS names `component`'s certificate carries in `namespace`.
pub fn dns_names(component: &str, namespace: &str, extra: &[String]) -> anyhow::Result<Vec<String>> {
    let services = K8S_COMPONENTS
        .iter()
        .find(|(c, _)| *c == component)
        .map(|(_, s)| *s)
        .with_context(|| format!("no component {component:?}"))?;
    let mut names = Vec::new();
    for s in services {
        names.push(s.to_string());
        names.push(format!("{s}.{namespace}"));
        names.push(format!("{s}.{namespace}.svc"));
        names.push(format!("{s}.{namespace}.svc.cluster.local"));
    }
    if component == "gateway" {
        names.extend(["localhost".to_string(), "127.0.0.1".to_string()]);
        names.extend(extra.iter().cloned());
    }
    names.dedup();
    Ok(names)
}

/// Writes the credentials; returns the kustomization's directory.
pub fn write_k8s(args: &K8sCredentialsArgs) -> anyhow::Result<PathBuf> {
    let ns = &args.namespace;
    let pki = DevPki::ensure_ca(&args.out)?;
    let certs = args.out.join("components");
    std::fs::create_dir_all(&certs)?;
    let ca = std::fs::read(pki.ca())?;
    let mut yaml = String::from(
        "# Written by `vlnav credentials k8s`: every component's certificate and the\n\
         # gateway's token hashes. Private keys: keep this directory out of version\n\
         # control. Apply before the stack: kubectl apply -k <this directory>\n",
    );
    for (component, _) in K8S_COMPONENTS {
        let (cert, key) = (certs.join(format!("{component}.pem")), certs.join(format!("{component}-key.pem")));
        pki.issue_service(component, &dns_names(component, ns, &args.gateway_names)?, &cert, &key)?;
        let data = [("ca.crt", ca.clone()), ("tls.crt", std::fs::read(&cert)?), ("tls.key", std::fs::read(&key)?)];
        secret(&mut yaml, &tls_secret_name(component), "kubernetes.io/tls", component, &data);
    }
    let tokens = vlnav_gateway::auth::ensure_dev_tokens(&args.out)?;
    secret(&mut yaml, TOKENS_SECRET, "Opaque", "gateway", &[("tokens.toml", std::fs::read(&tokens)?)]);
    for robot in &args.robots {
        pki.ensure_robot(robot)?;
    }
    vlnav_runtime::security::write_secret(&args.out.join("secrets.yaml"), &yaml)?;
    std::fs::write(
        args.out.join("kustomization.yaml"),
        format!(
            "apiVersion: kustomize.config.k8s.io/v1beta1\nkind: Kustomization\nnamespace: {ns}\nresources:\n  - secrets.yaml\n"
        ),
    )?;
    Ok(args.out.clone())
}

fn secret(yaml: &mut String, name: &str, kind: &str, component: &str, data: &[(&str, Vec<u8>)]) {
    let b64 = base64::engine::general_purpose::STANDARD;
    let _ = write!(
        yaml,
        "---\napiVersion: v1\nkind: Secret\nmetadata:\n  name: {name}\n  labels:\n    app.kubernetes.io/name: {component}\n    app.kubernetes.io/part-of: vlnav\ntype: {kind}\ndata:\n"
    );
    for (key, value) in data {
        let _ = writeln!(yaml, "  {key}: {}", b64.encode(value));
    }
}

/// What to run next, printed after writing.
pub fn next_steps(args: &K8sCredentialsArgs, dir: &Path) -> String {
    let pki = DevPki { dir: dir.to_path_buf() };
    let robots: String = args
        .robots
        .iter()
        .map(|r| {
            format!(
                "\n  robot {r}: vlnav-edge --tls-ca {} --tls-client-cert {} --tls-client-key {} ...",
                pki.ca().display(),
                pki.robot_cert(r).display(),
                pki.robot_key(r).display()
            )
        })
        .collect();
    format!(
        "credentials written to {d}\n  kubectl apply -k {d}          (the Secrets; then kubectl apply -k k8s/base or an overlay)\n  operator token: {d}/operator.token, viewer token: {d}/viewer.token\n  the CA's key {d}/ca-key.pem signs new certificates: keep it off the cluster{robots}",
        d = dir.display()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn revoking_writes_the_list_beside_the_ca_and_refuses_bad_input() {
        let dir = tempfile::tempdir().unwrap();
        let args = |f: &dyn Fn(&mut RevokeArgs)| {
            let mut a = RevokeArgs { dir: dir.path().to_path_buf(), ..Default::default() };
            f(&mut a);
            a
        };
        let e = revoke(&args(&|a| a.robots = vec!["husky-1".into()])).unwrap_err().to_string();
        assert!(e.contains("holds no ca.pem"), "{e}");
        let pki = DevPki::ensure(dir.path(), &["husky-2"]).unwrap();
        let e = revoke(&args(&|_| {})).unwrap_err().to_string();
        assert!(e.contains("--robot ID, --service NAME or --cert FILE"), "{e}");
        let e = revoke(&args(&|a| a.robots = vec!["../x".into()])).unwrap_err().to_string();
        assert!(e.contains("--robot \"../x\""), "{e}");
        let e = revoke(&args(&|a| a.services = vec!["".into()])).unwrap_err().to_string();
        assert!(e.contains("--service \"\""), "{e}");
        let e = format!("{:#}", revoke(&args(&|a| a.certs = vec![pki.robot_key("husky-2")])).unwrap_err());
        assert!(e.contains("not an X.509 certificate"), "{e}");
        assert!(!pki.revoked().exists(), "nothing written on bad input");

        let out = revoke(&args(&|a| {
            a.robots = vec!["husky-1".into()];
            a.services = vec!["planner".into()];
            a.certs = vec![pki.robot_cert("husky-2")];
            a.reason = "lost".into();
        }))
        .unwrap();
        assert!(out.contains("revoked spiffe://vlnav/robot/husky-1"), "{out}");
        assert!(out.contains("lists 3 revocations"), "{out}");
        let out = revoke(&args(&|a| a.robots = vec!["husky-1".into()])).unwrap();
        assert!(out.contains("already revoked: spiffe://vlnav/robot/husky-1"), "{out}");
        let list = vlnav_runtime::revocation::RevocationList::load(&pki.revoked()).unwrap();
        assert_eq!(list.entries.len(), 3);
        assert!(list.entries.iter().all(|e| e.reason == "lost" && e.revoked_unix.is_some()));
        let husky2 = vlnav_runtime::revocation::CertificateId::of_pem_file(&pki.robot_cert("husky-2")).unwrap();
        assert!(list.revokes(&husky2).unwrap().contains("certificate is revoked (lost)"));
    }

    #[test]
    fn a_robot_certificate_comes_from_the_existing_ca_and_touches_nothing_else_there() {
        let home = tempfile::tempdir().unwrap();
        let ca_dir = home.path().join("security");
        let args = |f: &dyn Fn(&mut RobotCredentialsArgs)| {
            let mut a = RobotCredentialsArgs { id: "husky-2".into(), ca_dir: ca_dir.clone(), out: None, gateway: None };
            f(&mut a);
            a
        };
        let e = format!("{:#}", issue_robot(&args(&|_| {})).unwrap_err());
        assert!(
            e.contains("--ca-dir")
                && e.contains("give the directory of an existing CA")
                && e.contains("is not a directory"),
            "{e}"
        );
        assert!(!ca_dir.exists(), "no CA is made");
        let pki = DevPki::ensure(&ca_dir, &["husky-1"]).unwrap();
        let e = issue_robot(&args(&|a| a.id = "../husky".into())).unwrap_err().to_string();
        assert!(e.contains("--id \"../husky\""), "{e}");
        let e = issue_robot(&args(&|a| a.gateway = Some("http://10.0.0.7:50051".into()))).unwrap_err().to_string();
        assert!(e.contains("https://HOST:PORT"), "{e}");
        let snapshot = |dir: &Path| {
            let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.is_file())
                .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap()))
                .collect();
            v.sort();
            v
        };
        let before = snapshot(&ca_dir);

        // Into a directory to copy to the robot: the CA's directory is untouched.
        let out = home.path().join("robot-husky-2");
        let (files, report) = issue_robot(&args(&|a| {
            a.out = Some(out.clone());
            a.gateway = Some("https://10.0.0.7:50051".into());
        }))
        .unwrap();
        assert_eq!(snapshot(&ca_dir), before, "nothing in the CA's directory changed");
        assert_eq!(std::fs::read(&files.ca).unwrap(), std::fs::read(pki.ca()).unwrap());
        let der = vlnav_runtime::security::pem_to_der(&std::fs::read(&files.cert).unwrap()).unwrap();
        assert_eq!(vlnav_runtime::security::robot_ids_of_peer(&[der]), vec!["husky-2".to_string()]);
        let flags = format!(
            "--tls-ca {} --tls-client-cert {} --tls-client-key {}",
            out.join("ca.pem").display(),
            out.join("robot-husky-2.pem").display(),
            out.join("robot-husky-2-key.pem").display()
        );
        assert!(report.contains(&flags), "{report}");
        assert!(report.contains("--robot-id husky-2 --gateway https://10.0.0.7:50051"), "{report}");
        assert!(
            report.contains("warning: the gateway's certificate") && report.contains("--gateway-name 10.0.0.7"),
            "{report}"
        );

        // Into the CA's directory: only the robot's two files are written.
        DevPki::ensure_named(&ca_dir, &[], &["10.0.0.7".into()]).unwrap();
        let before = snapshot(&ca_dir);
        let (files, report) = issue_robot(&args(&|a| a.gateway = Some("https://10.0.0.7:50051".into()))).unwrap();
        assert!(!report.contains("warning"), "{report}");
        assert_eq!(files.ca, pki.ca());
        let after = snapshot(&ca_dir);
        let changed: Vec<&String> = after.iter().filter(|f| !before.contains(f)).map(|(n, _)| n).collect();
        assert_eq!(changed, ["robot-husky-2-key.pem", "robot-husky-2.pem"]);
        assert_eq!(after.len(), before.len() + 2);

        // An --out holding another CA is refused; so is a CA whose key is not its own.
        let e = issue_robot(&args(&|a| a.out = Some(home.path().join("other")))).map(|_| ());
        assert!(e.is_ok());
        DevPki::ensure_ca(&home.path().join("other")).unwrap();
        let e = issue_robot(&args(&|a| a.out = Some(home.path().join("other")))).unwrap_err().to_string();
        assert!(e.contains("holds another CA"), "{e}");
        std::fs::copy(home.path().join("other/ca-key.pem"), pki.ca_key()).unwrap();
        let e = format!("{:#}", issue_robot(&args(&|_| {})).unwrap_err());
        assert!(e.contains("is not the key of"), "{e}");
    }

    #[test]
    fn the_gateway_address_must_be_https_and_its_host_a_name() {
        assert_eq!(gateway_host("https://10.0.0.7:50051").unwrap().as_deref(), Some("10.0.0.7"));
        assert_eq!(gateway_host("https://[fd00::7]:50051").unwrap().as_deref(), Some("fd00::7"));
        assert_eq!(gateway_host("https://gw.lab.example").unwrap().as_deref(), Some("gw.lab.example"));
        assert_eq!(gateway_host("https://$GATEWAY_HOST:50051").unwrap(), None);
        assert!(gateway_host("10.0.0.7:50051").is_err());
        assert!(gateway_host("https://0.0.0.0:50051").is_err());
    }

    #[test]
    fn a_scaled_stage_is_named_by_its_headless_service_in_every_spelling() {
        let names = dns_names("planner", "vlnav", &[]).unwrap();
        for n in ["planner", "planner-replicas", "planner-replicas.vlnav.svc", "planner.vlnav.svc.cluster.local"] {
            assert!(names.iter().any(|x| x == n), "{n} missing from {names:?}");
        }
        let gw = dns_names("gateway", "robots", &["vlnav.example.org".into()]).unwrap();
        assert!(gw.contains(&"gateway.robots.svc".to_string()) && gw.contains(&"vlnav.example.org".to_string()));
        assert!(dns_names("nope", "vlnav", &[]).is_err());
    }
}
