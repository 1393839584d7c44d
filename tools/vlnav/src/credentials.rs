//! `vlnav credentials k8s`: the certificates and tokens a Kubernetes
//! deployment reads from Secrets (k8s/base, docs/security.md), written as a
//! kustomization to apply before the stack. One CA signs a certificate per
//! component, valid for the names of that component's Services; the
//! gateway's token file holds only hashes.

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
