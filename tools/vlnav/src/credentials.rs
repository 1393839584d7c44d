//! `vlnav credentials k8s`: the certificates and tokens a Kubernetes
//! deployment reads from Secrets (k8s/base, docs/security.md), written as a
//! kustomization to apply before the stack. One CA signs a certificate per
//! component, valid for the names of that component's Services; the
//! gateway's token file holds only hashes.
//!
//! `vlnav credentials revoke`: adds robots, components or single
//! certificates to the revocation list beside the CA, which servers read
//! again within a second (`vlnav_runtime::revocation`).

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
