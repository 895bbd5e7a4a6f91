//! A Prometheus text endpoint: strips done and re-queued, strip latency,
//! bytes moved, workers alive, jobs queued and running.

use std::fmt::Write as _;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Upper bounds of the strip-latency histogram, seconds.
const BUCKETS: [f64; 10] = [0.01, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0];

/// Counters the coordinator updates as strips come and go.
#[derive(Default)]
pub struct Metrics {
    strips_done: AtomicU64,
    strips_retried: AtomicU64,
    bytes_received: AtomicU64,
    bytes_sent: AtomicU64,
    latency: Mutex<([u64; BUCKETS.len()], u64, f64)>,
}

/// Gauges read when the endpoint is scraped.
#[derive(Clone, Copy, Debug, Default)]
pub struct Gauges {
    /// Jobs waiting.
    pub queued: u64,
    /// Jobs rendering.
    pub running: u64,
    /// Workers whose last heartbeat was answered.
    pub workers_alive: u64,
    /// Workers known.
    pub workers: u64,
}

impl Metrics {
    /// A strip came back after `seconds` with `bytes` of pixels.
    pub fn strip_done(&self, seconds: f64, bytes: u64) {
        self.strips_done.fetch_add(1, Ordering::Relaxed);
        self.bytes_received.fetch_add(bytes, Ordering::Relaxed);
        let mut l = self.latency.lock().expect("lock");
        for (i, b) in BUCKETS.iter().enumerate() {
            if seconds <= *b {
                l.0[i] += 1;
            }
        }
        l.1 += 1;
        l.2 += seconds;
    }

    /// A strip was re-queued.
    pub fn strip_retried(&self) {
        self.strips_retried.fetch_add(1, Ordering::Relaxed);
    }

    /// A scene bundle of `bytes` went to a worker.
    pub fn bundle_sent(&self, bytes: u64) {
        self.bytes_sent.fetch_add(bytes, Ordering::Relaxed);
    }

    /// The Prometheus text exposition.
    pub fn render(&self, g: Gauges) -> String {
        let mut s = String::new();
        let mut counter = |name: &str, help: &str, v: u64| {
            let _ = writeln!(s, "# HELP {name} {help}\n# TYPE {name} counter\n{name} {v}");
        };
        counter("sylva_strips_done_total", "Strips rendered and returned by workers.", self.strips_done.load(Ordering::Relaxed));
        counter("sylva_strips_retried_total", "Strips re-queued after a worker failed.", self.strips_retried.load(Ordering::Relaxed));
        counter("sylva_bytes_received_total", "Bytes of strip pixels received from workers.", self.bytes_received.load(Ordering::Relaxed));
        counter("sylva_bytes_sent_total", "Bytes of scene bundles sent to workers.", self.bytes_sent.load(Ordering::Relaxed));
        for (name, help, v) in [
            ("sylva_jobs_queued", "Jobs waiting.", g.queued),
            ("sylva_jobs_running", "Jobs rendering.", g.running),
            ("sylva_workers_alive", "Workers answering heartbeats.", g.workers_alive),
            ("sylva_workers", "Workers known.", g.workers),
        ] {
            let _ = writeln!(s, "# HELP {name} {help}\n# TYPE {name} gauge\n{name} {v}");
        }
        let l = self.latency.lock().expect("lock");
        let _ = writeln!(s, "# HELP sylva_strip_seconds Strip render time on the worker.\n# TYPE sylva_strip_seconds histogram");
        for (b, c) in BUCKETS.iter().zip(l.0) {
            let _ = writeln!(s, "sylva_strip_seconds_bucket{{le=\"{b}\"}} {c}");
        }
        let _ = writeln!(s, "sylva_strip_seconds_bucket{{le=\"+Inf\"}} {}\nsylva_strip_seconds_sum {}\nsylva_strip_seconds_count {}", l.1, l.2, l.1);
        s
    }
}

/// Serves `GET /metrics` on `listener` with the counters and `gauges()`.
pub async fn serve(listener: tokio::net::TcpListener, metrics: std::sync::Arc<Metrics>, gauges: impl Fn() -> Gauges + Send + Sync + 'static) {
    let gauges = std::sync::Arc::new(gauges);
    loop {
        let Ok((mut sock, _)) = listener.accept().await else { continue };
        let (metrics, gauges) = (metrics.clone(), gauges.clone());
        tokio::spawn(async move {
            let mut buf = vec![0u8; 4096];
            let mut n = 0;
            while n < buf.len() {
                match sock.read(&mut buf[n..]).await {
                    Ok(0) | Err(_) => break,
                    Ok(k) => n += k,
                }
                if buf[..n].windows(4).any(|w| w == b"\r\n\r\n") {
                    break;
                }
            }
            let request = String::from_utf8_lossy(&buf[..n]);
            let reply = if request.starts_with("GET /metrics") {
                let body = metrics.render(gauges());
                format!("HTTP/1.1 200 OK\r\nContent-Type: text/plain; version=0.0.4\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}", body.len())
            } else {
                "HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n".to_string()
            };
            let _ = sock.write_all(reply.as_bytes()).await;
        });
    }
}
