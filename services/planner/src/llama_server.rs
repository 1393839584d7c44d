//! A llama.cpp `llama-server` child process serving a GGUF model on a free
//! loopback port, for the OpenAI-compatible backend's test and the backend
//! comparison (`examples/corpus.rs`). `deploy/llama-server.sh` builds the
//! binary into `<models-dir>/llama.cpp/bin/llama-server`.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Where `deploy/llama-server.sh` puts the binary.
pub fn default_binary(models_dir: &Path) -> PathBuf {
    models_dir.join("llama.cpp/bin/llama-server")
}

/// `$VLNAV_LLAMA_SERVER`, else [`default_binary`]; an error naming the
/// command that builds it when neither exists.
pub fn locate(models_dir: &Path) -> Result<PathBuf, String> {
    let bin = std::env::var_os("VLNAV_LLAMA_SERVER").map(PathBuf::from).unwrap_or_else(|| default_binary(models_dir));
    if bin.is_file() {
        Ok(bin)
    } else {
        Err(format!(
            "no llama-server at {}: build it once with `deploy/llama-server.sh` (~5 min on 2 cores; \
             VLNAV_MODELS_DIR={} deploy/llama-server.sh), or point VLNAV_LLAMA_SERVER at one",
            bin.display(),
            models_dir.display()
        ))
    }
}

/// A running server; killed when dropped.
pub struct LlamaServer {
    child: Child,
    port: u16,
}

impl LlamaServer {
    /// Starts `bin` serving `gguf` with `threads` threads and waits (up to
    /// `ready_within`) until `/health` answers 200.
    pub fn start(bin: &Path, gguf: &Path, threads: usize, ready_within: Duration) -> Result<LlamaServer, String> {
        if !gguf.is_file() {
            return Err(format!("missing {}: run deploy/fetch-models.sh", gguf.display()));
        }
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map_err(|e| format!("no free port: {e}"))?
            .port();
        let child = Command::new(bin)
            .arg("-m")
            .arg(gguf)
            .args(["--host", "127.0.0.1", "--port", &port.to_string(), "-c", "4096", "-np", "1"])
            .args(["-t", &threads.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("starting {}: {e}", bin.display()))?;
        let mut server = LlamaServer { child, port };
        let started = Instant::now();
        loop {
            if server.healthy() {
                return Ok(server);
            }
            if let Ok(Some(status)) = server.child.try_wait() {
                let mut err = String::new();
                let _ = server.child.stderr.take().map(|mut e| e.read_to_string(&mut err));
                let tail: String = err.chars().rev().take(2000).collect::<String>().chars().rev().collect();
                return Err(format!("llama-server exited with {status}: {tail}"));
            }
            if started.elapsed() > ready_within {
                return Err(format!("llama-server did not become healthy in {} s", ready_within.as_secs()));
            }
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    fn healthy(&self) -> bool {
        let Ok(mut s) = TcpStream::connect(("127.0.0.1", self.port)) else { return false };
        let _ = s.set_read_timeout(Some(Duration::from_secs(5)));
        let _ = s.write_all(b"GET /health HTTP/1.0\r\n\r\n");
        let mut buf = String::new();
        let _ = s.read_to_string(&mut buf);
        buf.starts_with("HTTP/1.1 200") || buf.starts_with("HTTP/1.0 200")
    }

    /// The OpenAI-compatible base URL, up to `/v1`.
    pub fn base_url(&self) -> String {
        format!("http://127.0.0.1:{}/v1", self.port)
    }
}

impl Drop for LlamaServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
