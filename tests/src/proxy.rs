//! A TCP proxy on loopback whose link can be broken on purpose: it passes
//! bytes, delays them, stalls them (a partition: sockets stay open, nothing
//! gets through), or cuts every connection and refuses new ones.
//!
//! The chaos tests put one between the edge agent and the gateway, and
//! between the gateway and one stage.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;
use vlnav_runtime::CancellationToken;

/// What the proxy does with the bytes of its connections.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Bytes go through as they come.
    Pass,
    /// Every chunk is delivered this long after it was read (pipelined: a
    /// latency, not a throughput limit).
    Delay(Duration),
    /// Nothing gets through either way: the proxy stops reading and writing,
    /// sockets stay open and new connections are accepted but stall, as in a
    /// partition where packets are lost and TCP keeps retrying. Bytes already
    /// read are delivered once the mode changes back.
    Blackhole,
    /// New connections are closed as soon as they are accepted.
    Refuse,
}

struct Shared {
    mode: watch::Sender<Mode>,
    /// Cancelled by [`Proxy::cut`]; every connection holds the one current when it opened.
    epoch: Mutex<CancellationToken>,
    accepted: AtomicU64,
}

/// A proxy from a loopback port to `upstream`; it stops when dropped.
pub struct Proxy {
    addr: SocketAddr,
    upstream: SocketAddr,
    shared: Arc<Shared>,
    stop: CancellationToken,
}

impl Proxy {
    /// Listens on an ephemeral loopback port and forwards to `upstream`.
    pub async fn start(upstream: SocketAddr) -> std::io::Result<Proxy> {
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared {
            mode: watch::channel(Mode::Pass).0,
            epoch: Mutex::new(CancellationToken::new()),
            accepted: AtomicU64::new(0),
        });
        let stop = CancellationToken::new();
        tokio::spawn(accept_loop(listener, upstream, shared.clone(), stop.clone()));
        Ok(Proxy { addr, upstream, shared, stop })
    }

    /// Where clients connect.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `http://` URI of [`Self::addr`].
    pub fn uri(&self) -> String {
        format!("http://{}", self.addr)
    }

    pub fn upstream(&self) -> SocketAddr {
        self.upstream
    }

    pub fn mode(&self) -> Mode {
        *self.shared.mode.borrow()
    }

    /// Connections accepted so far.
    pub fn accepted(&self) -> u64 {
        self.shared.accepted.load(Ordering::Relaxed)
    }

    pub fn set(&self, mode: Mode) {
        self.shared.mode.send_replace(mode);
    }

    pub fn pass(&self) {
        self.set(Mode::Pass);
    }

    pub fn delay(&self, by: Duration) {
        self.set(Mode::Delay(by));
    }

    pub fn blackhole(&self) {
        self.set(Mode::Blackhole);
    }

    /// Closes every open connection and refuses new ones until the mode changes.
    pub fn cut(&self) {
        self.set(Mode::Refuse);
        let mut epoch = self.shared.epoch.lock().unwrap_or_else(|p| p.into_inner());
        epoch.cancel();
        *epoch = CancellationToken::new();
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.stop.cancel();
        self.shared.epoch.lock().unwrap_or_else(|p| p.into_inner()).cancel();
    }
}

async fn accept_loop(listener: TcpListener, upstream: SocketAddr, shared: Arc<Shared>, stop: CancellationToken) {
    loop {
        let accepted = tokio::select! {
            _ = stop.cancelled() => return,
            a = listener.accept() => a,
        };
        let Ok((client, _)) = accepted else { continue };
        shared.accepted.fetch_add(1, Ordering::Relaxed);
        if *shared.mode.borrow() == Mode::Refuse {
            drop(client);
            continue;
        }
        let epoch = shared.epoch.lock().unwrap_or_else(|p| p.into_inner()).clone();
        let mode = shared.mode.subscribe();
        tokio::spawn(async move {
            let server = tokio::select! {
                _ = epoch.cancelled() => return,
                s = TcpStream::connect(upstream) => match s {
                    Ok(s) => s,
                    Err(_) => return,
                },
            };
            let _ = client.set_nodelay(true);
            let _ = server.set_nodelay(true);
            let conn = epoch.child_token();
            let (cr, cw) = client.into_split();
            let (sr, sw) = server.into_split();
            let up = pump(cr, sw, mode.clone(), conn.clone());
            let down = pump(sr, cw, mode, conn.clone());
            tokio::join!(up, down);
        });
    }
}

/// Waits until `mode` lets bytes through; false when the connection ends meanwhile.
async fn flowing(mode: &mut watch::Receiver<Mode>, conn: &CancellationToken) -> bool {
    tokio::select! {
        _ = conn.cancelled() => false,
        r = mode.wait_for(|m| !matches!(m, Mode::Blackhole)) => r.is_ok(),
    }
}

/// Copies one direction: a reader that honours the mode and stamps each
/// chunk with when it is due, and a writer that delivers it then. Either
/// side ending ends the connection (both directions).
async fn pump(
    mut from: tokio::net::tcp::OwnedReadHalf,
    mut to: tokio::net::tcp::OwnedWriteHalf,
    mode: watch::Receiver<Mode>,
    conn: CancellationToken,
) {
    let (tx, mut rx) = mpsc::unbounded_channel::<(Instant, Vec<u8>)>();
    let mut read_mode = mode.clone();
    let read_conn = conn.clone();
    let reader = async move {
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            if !flowing(&mut read_mode, &read_conn).await {
                break;
            }
            let n = tokio::select! {
                _ = read_conn.cancelled() => break,
                r = from.read(&mut buf) => match r {
                    Ok(0) | Err(_) => break,
                    Ok(n) => n,
                },
            };
            let due = match *read_mode.borrow() {
                Mode::Delay(d) => Instant::now() + d,
                _ => Instant::now(),
            };
            if tx.send((due, buf[..n].to_vec())).is_err() {
                break;
            }
        }
        read_conn.cancel();
    };
    let mut write_mode = mode;
    let write_conn = conn.clone();
    let writer = async move {
        while let Some((due, bytes)) = tokio::select! {
            _ = write_conn.cancelled() => None,
            m = rx.recv() => m,
        } {
            tokio::select! {
                _ = write_conn.cancelled() => break,
                _ = tokio::time::sleep_until(due) => {}
            }
            if !flowing(&mut write_mode, &write_conn).await {
                break;
            }
            let written = tokio::select! {
                _ = write_conn.cancelled() => break,
                w = to.write_all(&bytes) => w,
            };
            if written.is_err() {
                break;
            }
        }
        write_conn.cancel();
    };
    tokio::join!(reader, writer);
}

#[cfg(test)]
mod tests {
    use super::*;

    async fn echo_server() -> SocketAddr {
        let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr().unwrap();
        tokio::spawn(async move {
            while let Ok((mut s, _)) = l.accept().await {
                tokio::spawn(async move {
                    let (mut r, mut w) = s.split();
                    let _ = tokio::io::copy(&mut r, &mut w).await;
                });
            }
        });
        addr
    }

    async fn roundtrip(s: &mut TcpStream, within: Duration) -> Option<Duration> {
        let t = Instant::now();
        s.write_all(b"ping").await.ok()?;
        let mut b = [0u8; 4];
        tokio::time::timeout(within, s.read_exact(&mut b)).await.ok()?.ok()?;
        Some(t.elapsed())
    }

    #[tokio::test]
    async fn passes_delays_stalls_and_cuts() {
        let proxy = Proxy::start(echo_server().await).await.unwrap();
        let mut s = TcpStream::connect(proxy.addr()).await.unwrap();
        assert!(roundtrip(&mut s, Duration::from_secs(2)).await.is_some());
        proxy.delay(Duration::from_millis(200));
        let rtt = roundtrip(&mut s, Duration::from_secs(3)).await.expect("delayed, not lost");
        assert!(rtt >= Duration::from_millis(400), "{rtt:?}");
        proxy.blackhole();
        assert!(roundtrip(&mut s, Duration::from_millis(300)).await.is_none());
        proxy.pass();
        // The stalled ping arrives once the link heals.
        let mut b = [0u8; 4];
        tokio::time::timeout(Duration::from_secs(2), s.read_exact(&mut b)).await.unwrap().unwrap();
        proxy.cut();
        let mut b = [0u8; 1];
        let r = tokio::time::timeout(Duration::from_secs(2), s.read(&mut b)).await.unwrap();
        assert!(matches!(r, Ok(0) | Err(_)), "a cut connection is closed: {r:?}");
        let mut refused = TcpStream::connect(proxy.addr()).await.unwrap();
        let r = tokio::time::timeout(Duration::from_secs(2), refused.read(&mut b)).await.unwrap();
        assert!(matches!(r, Ok(0) | Err(_)), "refused: {r:?}");
        proxy.pass();
        let mut s = TcpStream::connect(proxy.addr()).await.unwrap();
        assert!(roundtrip(&mut s, Duration::from_secs(2)).await.is_some());
    }
}
