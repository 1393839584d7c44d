//! Ingest cost of the OTLP receiver: one Export request of 512 spans (the
//! SDK batch exporter's default batch) over a real loopback gRPC connection,
//! converted and appended to the span files.

use std::sync::Arc;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use opentelemetry_proto::tonic::collector::trace::v1::ExportTraceServiceRequest;
use opentelemetry_proto::tonic::collector::trace::v1::trace_service_client::TraceServiceClient;
use opentelemetry_proto::tonic::common::v1::{AnyValue, KeyValue, any_value};
use opentelemetry_proto::tonic::resource::v1::Resource;
use opentelemetry_proto::tonic::trace::v1::{ResourceSpans, ScopeSpans, Span};
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use vlnav_traces::{SpanStore, serve_receiver};

const BATCH: usize = 512;

fn kv(key: &str, v: any_value::Value) -> KeyValue {
    KeyValue { key: key.into(), value: Some(AnyValue { value: Some(v) }), ..Default::default() }
}

fn request(batch_no: u64) -> ExportTraceServiceRequest {
    let mut trace_id = [0u8; 16];
    trace_id[..8].copy_from_slice(&(batch_no + 1).to_be_bytes());
    trace_id[15] = 1;
    let spans = (0..BATCH as u64)
        .map(|i| Span {
            trace_id: trace_id.to_vec(),
            span_id: (i + 1).to_be_bytes().to_vec(),
            parent_span_id: if i == 0 { vec![] } else { 1u64.to_be_bytes().to_vec() },
            name: ["detect", "segment", "subgoal", "local-plan"][(i % 4) as usize].into(),
            kind: 2,
            start_time_unix_nano: 1_763_700_000_000_000_000 + i * 1_000_000,
            end_time_unix_nano: 1_763_700_000_000_000_000 + i * 1_000_000 + 800_000,
            attributes: vec![
                kv("rpc.system", any_value::Value::StringValue("grpc".into())),
                kv("rpc.method", any_value::Value::StringValue("Detect".into())),
                kv("rpc.grpc.status_code", any_value::Value::IntValue(0)),
            ],
            ..Default::default()
        })
        .collect();
    ExportTraceServiceRequest {
        resource_spans: vec![ResourceSpans {
            resource: Some(Resource {
                attributes: vec![kv("service.name", any_value::Value::StringValue("vlnav-detector".into()))],
                ..Default::default()
            }),
            scope_spans: vec![ScopeSpans { spans, ..Default::default() }],
            ..Default::default()
        }],
    }
}

fn bench(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let store = Arc::new(SpanStore::open(dir.path()).unwrap());
    let shutdown = CancellationToken::new();
    let endpoint = rt.block_on(async {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let endpoint = format!("http://{}", listener.local_addr().unwrap());
        tokio::spawn(serve_receiver(listener, store.clone(), shutdown.clone()));
        endpoint
    });
    let mut client = rt.block_on(TraceServiceClient::connect(endpoint)).unwrap();
    let mut group = c.benchmark_group("otlp receiver");
    group.throughput(Throughput::Elements(BATCH as u64));
    let mut n = 0u64;
    group.bench_function("export 512 spans (loopback gRPC, stored to disk)", |b| {
        b.iter(|| {
            n += 1;
            rt.block_on(client.export(request(n % 64))).unwrap();
        })
    });
    group.finish();
    shutdown.cancel();
}

criterion_group!(benches, bench);
criterion_main!(benches);
