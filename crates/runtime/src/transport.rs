//! HTTP/2 settings both ends of every connection use: [`client`](crate::client)
//! and [`server`](crate::server) read them from here.

use std::time::Duration;

/// HTTP/2 pings on idle connections, both ends.
pub const KEEPALIVE_INTERVAL: Duration = Duration::from_secs(10);
/// A ping unanswered this long closes the connection.
pub const KEEPALIVE_TIMEOUT: Duration = Duration::from_secs(10);

/// HTTP/2 flow-control windows sized for RGB-D frames, bytes.
pub const STREAM_WINDOW: u32 = 16 * 1024 * 1024;
pub const CONNECTION_WINDOW: u32 = 64 * 1024 * 1024;
