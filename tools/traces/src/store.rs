//! Spans kept in memory and appended to one JSON-lines file per trace
//! (`<dir>/<trace-id>.jsonl`), so that another process — `vlnav profile`
//! while `vlnav up` is still running — reads a trace by opening one file.

use std::collections::{HashMap, HashSet, VecDeque};
use std::fs::{self, OpenOptions};
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::span::{IdError, Span, normalize_trace_id};

/// Spans kept in memory before the oldest traces are dropped from memory
/// (their files stay).
pub const DEFAULT_MEMORY_SPANS: usize = 200_000;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error(transparent)]
    BadTraceId(#[from] IdError),
    #[error("span store {path}: {source}")]
    Io { path: PathBuf, source: io::Error },
}

fn io_at(path: &Path) -> impl FnOnce(io::Error) -> StoreError + '_ {
    move |source| StoreError::Io { path: path.to_path_buf(), source }
}

/// Received spans, by trace, in memory and on disk.
pub struct SpanStore {
    dir: PathBuf,
    memory_limit: usize,
    inner: Mutex<Memory>,
}

#[derive(Default)]
struct Memory {
    by_trace: HashMap<String, Vec<Span>>,
    /// Traces in the order they were first seen, for eviction.
    order: VecDeque<String>,
    spans: usize,
}

impl SpanStore {
    /// Opens (creating it if needed) the span directory `dir`.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self, StoreError> {
        Self::with_memory_limit(dir, DEFAULT_MEMORY_SPANS)
    }

    /// Like [`SpanStore::open`], keeping at most `memory_limit` spans in memory.
    pub fn with_memory_limit(dir: impl AsRef<Path>, memory_limit: usize) -> Result<Self, StoreError> {
        let dir = dir.as_ref().to_path_buf();
        fs::create_dir_all(&dir).map_err(io_at(&dir))?;
        Ok(Self { dir, memory_limit: memory_limit.max(1), inner: Mutex::new(Memory::default()) })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The file a trace's spans are appended to.
    pub fn trace_file(dir: &Path, trace_id: &str) -> Result<PathBuf, IdError> {
        Ok(dir.join(format!("{}.jsonl", normalize_trace_id(trace_id)?)))
    }

    /// Appends spans to their traces' files (one `write` per trace, so lines
    /// from concurrent writers never interleave) and keeps them in memory.
    /// Spans whose trace id is not a valid W3C id are refused as a whole batch
    /// error, before anything is written.
    pub fn insert(&self, spans: Vec<Span>) -> Result<(), StoreError> {
        let mut grouped: HashMap<String, Vec<Span>> = HashMap::new();
        for mut span in spans {
            span.trace_id = normalize_trace_id(&span.trace_id)?;
            grouped.entry(span.trace_id.clone()).or_default().push(span);
        }
        let mut memory = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        for (trace_id, spans) in grouped {
            let path = Self::trace_file(&self.dir, &trace_id)?;
            let mut buf = Vec::with_capacity(spans.len() * 256);
            for span in &spans {
                serde_json::to_writer(&mut buf, span)
                    .map_err(|e| StoreError::Io { path: path.clone(), source: e.into() })?;
                buf.push(b'\n');
            }
            let mut file = OpenOptions::new().create(true).append(true).open(&path).map_err(io_at(&path))?;
            file.write_all(&buf).map_err(io_at(&path))?;
            memory.add(trace_id, spans);
        }
        memory.evict(self.memory_limit);
        Ok(())
    }

    /// Every span of a trace this store or any other writer of its directory
    /// received, each once, ordered by start time. Empty if none arrived.
    pub fn spans_of_trace(&self, trace_id: &str) -> Result<Vec<Span>, StoreError> {
        let trace_id = normalize_trace_id(trace_id)?;
        let mut spans = read_trace(&self.dir, &trace_id)?;
        let memory = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(kept) = memory.by_trace.get(&trace_id) {
            spans.extend(kept.iter().cloned());
        }
        Ok(dedup_sorted(spans))
    }

    /// Trace ids that have a file in the directory, most recently written first.
    pub fn trace_ids(&self) -> Result<Vec<String>, StoreError> {
        let mut found = Vec::new();
        for entry in fs::read_dir(&self.dir).map_err(io_at(&self.dir))? {
            let entry = entry.map_err(io_at(&self.dir))?;
            let name = entry.file_name();
            let Some(stem) = name.to_str().and_then(|n| n.strip_suffix(".jsonl")) else { continue };
            if let Ok(id) = normalize_trace_id(stem) {
                let modified = entry.metadata().and_then(|m| m.modified()).ok();
                found.push((modified, id));
            }
        }
        found.sort_by(|a, b| b.0.cmp(&a.0).then_with(|| a.1.cmp(&b.1)));
        Ok(found.into_iter().map(|(_, id)| id).collect())
    }

    /// Spans currently held in memory.
    pub fn memory_spans(&self) -> usize {
        self.inner.lock().unwrap_or_else(|p| p.into_inner()).spans
    }
}

impl Memory {
    fn add(&mut self, trace_id: String, spans: Vec<Span>) {
        self.spans += spans.len();
        match self.by_trace.get_mut(&trace_id) {
            Some(kept) => kept.extend(spans),
            None => {
                self.order.push_back(trace_id.clone());
                self.by_trace.insert(trace_id, spans);
            }
        }
    }

    fn evict(&mut self, limit: usize) {
        // The newest trace stays even when it alone is over the limit.
        while self.spans > limit && self.order.len() > 1 {
            if let Some(oldest) = self.order.pop_front()
                && let Some(spans) = self.by_trace.remove(&oldest)
            {
                self.spans -= spans.len();
            }
        }
    }
}

/// Reads a trace's file from a span directory without opening a store: the
/// spans in file order, skipping a line another process is still writing
/// (or left torn by a crash). A trace with no file has no spans.
pub fn read_trace(dir: &Path, trace_id: &str) -> Result<Vec<Span>, StoreError> {
    let path = SpanStore::trace_file(dir, trace_id)?;
    let file = match fs::File::open(&path) {
        Ok(f) => f,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(StoreError::Io { path, source: e }),
    };
    let mut spans = Vec::new();
    for line in BufReader::new(file).lines() {
        let line = line.map_err(io_at(&path))?;
        if line.trim().is_empty() {
            continue;
        }
        match serde_json::from_str::<Span>(&line) {
            Ok(span) => spans.push(span),
            Err(e) => tracing::warn!(path = %path.display(), error = %e, "skipping unreadable span line"),
        }
    }
    Ok(spans)
}

/// One copy of each span id (exporters retry, so a span may arrive twice),
/// ordered by start time, then span id.
pub fn dedup_sorted(spans: Vec<Span>) -> Vec<Span> {
    let mut seen = HashSet::new();
    let mut out: Vec<Span> = spans.into_iter().filter(|s| seen.insert(s.span_id.clone())).collect();
    out.sort_by(|a, b| a.start_ns.cmp(&b.start_ns).then_with(|| a.span_id.cmp(&b.span_id)));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::span::{SpanKind, SpanStatus};

    fn span(trace: &str, id: u64, start: u64) -> Span {
        Span {
            trace_id: trace.to_string(),
            span_id: format!("{id:016x}"),
            parent_id: None,
            name: "detect".into(),
            service: "vlnav-detector".into(),
            kind: SpanKind::Server,
            start_ns: start,
            end_ns: start + 10,
            attributes: Default::default(),
            status: SpanStatus::Ok,
        }
    }

    const T1: &str = "4bf92f3577b34da6a3ce929d0e0e4736";
    const T2: &str = "0af7651916cd43dd8448eb211c80319c";

    #[test]
    fn spans_are_written_per_trace_and_read_back_by_another_store() {
        let dir = tempfile::tempdir().unwrap();
        let writer = SpanStore::open(dir.path()).unwrap();
        writer.insert(vec![span(T1, 2, 20), span(T2, 1, 5), span(T1, 1, 10)]).unwrap();
        writer.insert(vec![span(T1, 3, 15)]).unwrap();

        // A second process opens the same directory.
        let reader = SpanStore::open(dir.path()).unwrap();
        let got = reader.spans_of_trace(T1).unwrap();
        let ids: Vec<&str> = got.iter().map(|s| s.span_id.as_str()).collect();
        assert_eq!(ids, ["0000000000000001", "0000000000000003", "0000000000000002"]);
        assert_eq!(reader.spans_of_trace(T2).unwrap().len(), 1);
        assert_eq!(reader.memory_spans(), 0);
        assert_eq!(writer.memory_spans(), 4);
        let mut ids = reader.trace_ids().unwrap();
        ids.sort();
        assert_eq!(ids, [T2, T1]);
        assert!(reader.spans_of_trace("0123456789abcdef0123456789abcdef").unwrap().is_empty());
    }

    #[test]
    fn duplicate_deliveries_count_once() {
        let dir = tempfile::tempdir().unwrap();
        let store = SpanStore::open(dir.path()).unwrap();
        store.insert(vec![span(T1, 1, 10)]).unwrap();
        store.insert(vec![span(T1, 1, 10)]).unwrap();
        assert_eq!(store.spans_of_trace(T1).unwrap().len(), 1);
    }

    #[test]
    fn torn_lines_are_skipped() {
        let dir = tempfile::tempdir().unwrap();
        let store = SpanStore::open(dir.path()).unwrap();
        store.insert(vec![span(T1, 1, 10)]).unwrap();
        let path = SpanStore::trace_file(dir.path(), T1).unwrap();
        let mut f = OpenOptions::new().append(true).open(&path).unwrap();
        f.write_all(b"{\"trace_id\":\"4bf9").unwrap();
        assert_eq!(read_trace(dir.path(), T1).unwrap().len(), 1);
    }

    #[test]
    fn invalid_trace_ids_are_refused_before_touching_the_disk() {
        let dir = tempfile::tempdir().unwrap();
        let store = SpanStore::open(dir.path()).unwrap();
        let err = store.insert(vec![span(T1, 1, 1), span("../../x", 2, 2)]).unwrap_err();
        assert!(matches!(err, StoreError::BadTraceId(IdError::NotHex { .. })), "{err}");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
        assert!(matches!(store.spans_of_trace("zz"), Err(StoreError::BadTraceId(_))));
    }

    #[test]
    fn memory_keeps_the_newest_traces_within_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let store = SpanStore::with_memory_limit(dir.path(), 3).unwrap();
        store.insert(vec![span(T1, 1, 1), span(T1, 2, 2)]).unwrap();
        store.insert(vec![span(T2, 3, 3), span(T2, 4, 4)]).unwrap();
        assert_eq!(store.memory_spans(), 2);
        // Evicted from memory, still on disk.
        assert_eq!(store.spans_of_trace(T1).unwrap().len(), 2);
    }
}
