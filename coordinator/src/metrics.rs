//! The Prometheus endpoint: strips done and re-queued, strip latency, bytes
//! moved, workers alive, jobs queued and running.
//!
//! `prometheus-client` keeps the series and writes the OpenMetrics text;
//! axum routes; hyper runs each connection so that idle clients time out.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use prometheus_client::collector::Collector;
use prometheus_client::encoding::{DescriptorEncoder, EncodeMetric};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::metrics::histogram::Histogram;
use prometheus_client::registry::{Registry, Unit};
use sylva_proto::sync::lock;
use tokio::net::{TcpListener, TcpStream};

/// Upper bounds of the strip-latency histogram, seconds.
const BUCKETS: [f64; 10] = [0.01, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0];

/// What `prometheus-client`'s text encoder writes; Prometheus reads it natively.
const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

/// Counters the coordinator updates as strips come and go.
#[derive(Debug)]
pub struct Metrics {
    strips_done: Counter,
    strips_retried: Counter,
    bytes_received: Counter,
    bytes_sent: Counter,
    latency: Histogram,
}

impl Default for Metrics {
    fn default() -> Self {
        Self {
            strips_done: Counter::default(),
            strips_retried: Counter::default(),
            bytes_received: Counter::default(),
            bytes_sent: Counter::default(),
            latency: Histogram::new(BUCKETS),
        }
    }
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
    /// 1 while the database takes writes, 0 while it refuses them.
    pub store_healthy: u64,
}

impl Metrics {
    /// A strip came back after `seconds` with `bytes` of pixels.
    pub fn strip_done(&self, seconds: f64, bytes: u64) {
        self.strips_done.inc();
        self.bytes_received.inc_by(bytes);
        self.latency.observe(seconds);
    }

    /// A strip was re-queued.
    pub fn strip_retried(&self) {
        self.strips_retried.inc();
    }

    /// A scene bundle of `bytes` went to a worker.
    pub fn bundle_sent(&self, bytes: u64) {
        self.bytes_sent.inc_by(bytes);
    }

    /// A registry over these counters (handles share their values) and `gauges`.
    fn registry(&self, gauges: impl Fn() -> Gauges + Send + Sync + 'static) -> Registry {
        let mut r = Registry::default();
        // Counters get `_total` appended when encoded.
        r.register(
            "sylva_strips_done",
            "Strips rendered and returned by workers.",
            self.strips_done.clone(),
        );
        r.register(
            "sylva_strips_retried",
            "Strips re-queued after a worker failed.",
            self.strips_retried.clone(),
        );
        r.register(
            "sylva_bytes_received",
            "Bytes of strip pixels received from workers.",
            self.bytes_received.clone(),
        );
        r.register(
            "sylva_bytes_sent",
            "Bytes of scene bundles sent to workers.",
            self.bytes_sent.clone(),
        );
        r.register_with_unit(
            "sylva_strip",
            "Strip render time on the worker.",
            Unit::Seconds,
            self.latency.clone(),
        );
        r.register_collector(Box::new(GaugeCollector(Box::new(gauges))));
        r
    }
}

/// Reads the coordinator's state on each scrape rather than mirroring it.
struct GaugeCollector(Box<dyn Fn() -> Gauges + Send + Sync>);

impl std::fmt::Debug for GaugeCollector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("GaugeCollector")
    }
}

impl Collector for GaugeCollector {
    fn encode(&self, mut encoder: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let g = (self.0)();
        for (name, help, v) in [
            ("sylva_jobs_queued", "Jobs waiting.", g.queued),
            ("sylva_jobs_running", "Jobs rendering.", g.running),
            ("sylva_workers_alive", "Workers answering heartbeats.", g.workers_alive),
            ("sylva_workers", "Workers known.", g.workers),
            ("sylva_store_healthy", "1 while the database takes writes.", g.store_healthy),
        ] {
            let gauge = ConstGauge::new(v);
            gauge.encode(encoder.encode_descriptor(name, help, None, gauge.metric_type())?)?;
        }
        Ok(())
    }
}

/// Limits that keep slow or idle clients from holding the server.
#[derive(Clone, Copy, Debug)]
pub struct MetricsServerConfig {
    /// Time a client has to send a whole request header; also how long a
    /// keep-alive connection may sit idle before it is closed.
    pub header_read_timeout: Duration,
    /// Connections served at once; later ones wait in the listen backlog.
    pub max_connections: usize,
    /// Connections one address may hold at once; more are closed as soon
    /// as they are accepted, so one client cannot starve the others.
    pub per_client: usize,
}

impl Default for MetricsServerConfig {
    fn default() -> Self {
        Self { header_read_timeout: Duration::from_secs(10), max_connections: 512, per_client: 32 }
    }
}

/// The connection a request came on: its peer, and a way for a handler to
/// close it (an event stream its client stopped reading).
#[derive(Clone, Debug)]
pub struct Connection {
    /// The client's address.
    pub peer: SocketAddr,
    /// Notified to close the connection at once.
    pub close: Arc<tokio::sync::Notify>,
}

/// Serves `GET /metrics` on `listener` with the counters and `gauges()`, with default limits.
pub async fn serve(
    listener: TcpListener,
    metrics: Arc<Metrics>,
    gauges: impl Fn() -> Gauges + Send + Sync + 'static,
) {
    serve_with(listener, metrics, gauges, MetricsServerConfig::default()).await
}

/// Serves `GET /metrics` on `listener` under `config`'s limits; never returns.
pub async fn serve_with(
    listener: TcpListener,
    metrics: Arc<Metrics>,
    gauges: impl Fn() -> Gauges + Send + Sync + 'static,
    config: MetricsServerConfig,
) {
    let listener = Arc::new(listener);
    let accept = move || {
        let l = listener.clone();
        async move { l.accept().await }
    };
    accept_loop(accept, router(metrics.registry(gauges)), config).await
}

/// Serves `app` on `listener` under the default limits (slow and idle
/// clients closed, connections capped); never returns. The dashboard's server.
pub async fn serve_app(listener: TcpListener, app: axum::Router) {
    let listener = Arc::new(listener);
    let accept = move || {
        let l = listener.clone();
        async move { l.accept().await }
    };
    accept_loop(accept, app, MetricsServerConfig::default()).await
}

/// `/metrics` answers GET (and HEAD); axum answers 405 to other methods and 404 elsewhere.
fn router(registry: Registry) -> axum::Router {
    axum::Router::new().route("/metrics", axum::routing::get(scrape)).with_state(Arc::new(registry))
}

async fn scrape(State(registry): State<Arc<Registry>>) -> Response {
    let mut body = String::new();
    match prometheus_client::encoding::text::encode(&mut body, &registry) {
        Ok(()) => ([(header::CONTENT_TYPE, CONTENT_TYPE)], body).into_response(),
        Err(_) => StatusCode::INTERNAL_SERVER_ERROR.into_response(),
    }
}

/// Accepts connections from `accept` (a parameter so tests can inject
/// errors) and serves each with `app` until the server is dropped.
async fn accept_loop<A, F>(mut accept: A, app: axum::Router, config: MetricsServerConfig)
where
    A: FnMut() -> F,
    F: Future<Output = std::io::Result<(TcpStream, SocketAddr)>>,
{
    const FIRST_BACKOFF: Duration = Duration::from_millis(100);
    const MAX_BACKOFF: Duration = Duration::from_secs(1);
    let slots = Arc::new(tokio::sync::Semaphore::new(config.max_connections.max(1)));
    let per_client = ClientCounts::default();
    let mut http = hyper::server::conn::http1::Builder::new();
    // hyper re-arms this timer whenever it waits for a request head, so it
    // closes silent new connections and idle keep-alive ones alike.
    http.timer(TokioTimer::new()).header_read_timeout(config.header_read_timeout);
    let mut backoff = FIRST_BACKOFF;
    loop {
        // Taking a slot before accepting leaves extra clients queued in the
        // kernel's backlog instead of growing tasks here.
        let Ok(permit) = slots.clone().acquire_owned().await else { return };
        let (stream, peer) = match accept().await {
            Ok(accepted) => accepted,
            Err(e) => {
                // Errors such as EMFILE persist until something closes, so
                // retrying at once would spin.
                tracing::warn!(error = %e, "http: accept failed; retrying in {backoff:?}");
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(MAX_BACKOFF);
                continue;
            }
        };
        backoff = FIRST_BACKOFF;
        // One address holds at most `per_client` connections: the next is
        // closed unanswered, its slot free for someone else at once.
        let Some(held) = per_client.take(peer.ip(), config.per_client) else {
            drop(stream);
            continue;
        };
        let connection = Connection { peer, close: Arc::new(tokio::sync::Notify::new()) };
        let close = connection.close.clone();
        let app = app.clone().layer(axum::Extension(connection));
        let conn = http.serve_connection(TokioIo::new(stream), TowerToHyperService::new(app));
        tokio::spawn(async move {
            tokio::select! {
                _ = conn => {}
                _ = close.notified() => {}
            }
            drop((permit, held));
        });
    }
}

/// Things (connections, event streams) held per client address, each
/// counted while its [`ClientSlot`] lives.
#[derive(Clone, Debug, Default)]
pub struct ClientCounts(Arc<std::sync::Mutex<std::collections::HashMap<std::net::IpAddr, usize>>>);

/// One thing a client holds, counted until dropped.
pub struct ClientSlot(ClientCounts, std::net::IpAddr);

impl ClientCounts {
    /// Counts one more for `ip`, unless it holds `cap` already.
    pub fn take(&self, ip: std::net::IpAddr, cap: usize) -> Option<ClientSlot> {
        let mut c = lock(&self.0);
        let n = c.entry(ip).or_insert(0);
        if *n >= cap.max(1) {
            return None;
        }
        *n += 1;
        Some(ClientSlot(self.clone(), ip))
    }
}

impl Drop for ClientSlot {
    fn drop(&mut self) {
        let mut c = lock(&(self.0).0);
        if let Some(n) = c.get_mut(&self.1) {
            *n -= 1;
            if *n == 0 {
                c.remove(&self.1);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
    use std::time::Instant;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    const CLOSE: &str = "Connection: close\r\n";

    async fn start(
        config: MetricsServerConfig,
        metrics: Arc<Metrics>,
        gauges: impl Fn() -> Gauges + Send + Sync + 'static,
    ) -> SocketAddr {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        tokio::spawn(serve_with(listener, metrics, gauges, config));
        addr
    }

    /// Sends `method path` and reads to EOF; returns the status, the head and the body.
    async fn request(
        addr: SocketAddr,
        method: &str,
        path: &str,
        extra: &str,
    ) -> (u16, String, String) {
        let mut sock = TcpStream::connect(addr).await.unwrap();
        sock.write_all(format!("{method} {path} HTTP/1.1\r\nHost: x\r\n{extra}\r\n").as_bytes())
            .await
            .unwrap();
        let mut text = String::new();
        tokio::time::timeout(Duration::from_secs(5), sock.read_to_string(&mut text))
            .await
            .expect("reply in time")
            .unwrap();
        split(&text)
    }

    fn split(text: &str) -> (u16, String, String) {
        let (head, body) =
            text.split_once("\r\n\r\n").unwrap_or_else(|| panic!("a reply: {text:?}"));
        (head[9..12].parse().unwrap(), head.to_ascii_lowercase(), body.to_string())
    }

    /// Reads until the peer closes; fails after `limit`.
    async fn read_until_closed(sock: &mut TcpStream, limit: Duration) -> Vec<u8> {
        let mut out = Vec::new();
        tokio::time::timeout(limit, async {
            let mut buf = [0u8; 4096];
            // A reset counts as closed too.
            while let Ok(n @ 1..) = sock.read(&mut buf).await {
                out.extend_from_slice(&buf[..n]);
            }
        })
        .await
        .expect("server closed the connection");
        out
    }

    #[tokio::test]
    async fn metrics_lists_every_series_with_gauges_read_at_scrape_time() {
        let metrics = Arc::new(Metrics::default());
        metrics.strip_done(0.07, 1000);
        metrics.strip_done(3.0, 24);
        metrics.strip_retried();
        metrics.bundle_sent(512);
        let queued = Arc::new(AtomicU64::new(2));
        let q = queued.clone();
        let gauges = move || Gauges {
            queued: q.load(Ordering::Relaxed),
            running: 1,
            workers_alive: 3,
            workers: 4,
            store_healthy: 1,
        };
        let addr = start(MetricsServerConfig::default(), metrics, gauges).await;

        let (status, head, body) = request(addr, "GET", "/metrics", CLOSE).await;
        assert_eq!(status, 200, "{head}");
        assert!(head.contains("content-type: application/openmetrics-text"), "{head}");
        let value = |body: &str, series: &str| -> f64 {
            let line = body
                .lines()
                .find(|l| l.starts_with(&format!("{series} ")))
                .unwrap_or_else(|| panic!("{series} in {body}"));
            line.rsplit(' ').next().unwrap().parse().unwrap()
        };
        for (series, want) in [
            ("sylva_strips_done_total", 2.0),
            ("sylva_strips_retried_total", 1.0),
            ("sylva_bytes_received_total", 1024.0),
            ("sylva_bytes_sent_total", 512.0),
            ("sylva_jobs_queued", 2.0),
            ("sylva_jobs_running", 1.0),
            ("sylva_workers_alive", 3.0),
            ("sylva_workers", 4.0),
            ("sylva_store_healthy", 1.0),
            ("sylva_strip_seconds_count", 2.0),
            ("sylva_strip_seconds_sum", 3.07),
            ("sylva_strip_seconds_bucket{le=\"0.05\"}", 0.0),
            ("sylva_strip_seconds_bucket{le=\"0.1\"}", 1.0),
            ("sylva_strip_seconds_bucket{le=\"2.5\"}", 1.0),
            ("sylva_strip_seconds_bucket{le=\"5.0\"}", 2.0),
            ("sylva_strip_seconds_bucket{le=\"+Inf\"}", 2.0),
        ] {
            assert!((value(&body, series) - want).abs() < 1e-9, "{series} in {body}");
        }
        let bounds: Vec<f64> = body
            .lines()
            .filter_map(|l| l.strip_prefix("sylva_strip_seconds_bucket{le=\""))
            .filter_map(|l| l.split('"').next()?.parse().ok())
            .filter(|b: &f64| b.is_finite())
            .collect();
        assert_eq!(bounds, BUCKETS, "{body}");
        assert!(body.contains("# TYPE sylva_strip_seconds histogram"), "{body}");

        // The callback runs on every scrape.
        queued.store(7, Ordering::Relaxed);
        let (_, _, body) = request(addr, "GET", "/metrics", CLOSE).await;
        assert_eq!(value(&body, "sylva_jobs_queued"), 7.0);
    }

    #[tokio::test]
    async fn other_paths_are_404_and_other_methods_405() {
        let addr = start(MetricsServerConfig::default(), Arc::default(), Gauges::default).await;
        for path in ["/", "/metric", "/metrics/x", "/favicon.ico"] {
            assert_eq!(request(addr, "GET", path, CLOSE).await.0, 404, "{path}");
        }
        for method in ["POST", "PUT", "DELETE"] {
            let (status, head, _) =
                request(addr, method, "/metrics", "Content-Length: 0\r\nConnection: close\r\n")
                    .await;
            assert_eq!(status, 405, "{method}");
            assert!(head.contains("allow: get,head"), "{head}");
        }
    }

    #[tokio::test]
    async fn idle_and_half_sent_and_keep_alive_connections_are_closed() {
        let timeout = Duration::from_millis(300);
        let config = MetricsServerConfig { header_read_timeout: timeout, ..Default::default() };
        let addr = start(config, Arc::default(), Gauges::default).await;

        // Connects and says nothing.
        let t = Instant::now();
        let mut silent = TcpStream::connect(addr).await.unwrap();
        read_until_closed(&mut silent, Duration::from_secs(3)).await;
        assert!(t.elapsed() >= timeout - Duration::from_millis(50), "{:?}", t.elapsed());

        // Sends part of a header and stops; hyper may answer 408 before closing.
        let t = Instant::now();
        let mut partial = TcpStream::connect(addr).await.unwrap();
        partial.write_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\n").await.unwrap();
        let reply = read_until_closed(&mut partial, Duration::from_secs(3)).await;
        assert!(t.elapsed() >= timeout - Duration::from_millis(50), "{:?}", t.elapsed());
        assert!(
            reply.is_empty() || reply.starts_with(b"HTTP/1.1 408"),
            "{}",
            String::from_utf8_lossy(&reply)
        );

        // A keep-alive client gets its reply, goes quiet, and is dropped.
        let mut kept = TcpStream::connect(addr).await.unwrap();
        kept.write_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n").await.unwrap();
        let t = Instant::now();
        let reply = read_until_closed(&mut kept, Duration::from_secs(3)).await;
        let reply = String::from_utf8(reply).unwrap();
        assert!(reply.starts_with("HTTP/1.1 200") && reply.ends_with("# EOF\n"), "{reply}");
        assert!(
            t.elapsed() >= timeout - Duration::from_millis(50),
            "kept alive for a while: {:?}",
            t.elapsed()
        );
    }

    #[tokio::test]
    async fn connections_beyond_the_cap_wait_for_a_slot() {
        let config = MetricsServerConfig {
            header_read_timeout: Duration::from_secs(10),
            max_connections: 2,
            ..Default::default()
        };
        let addr = start(config, Arc::default(), Gauges::default).await;
        let hog1 = TcpStream::connect(addr).await.unwrap();
        let hog2 = TcpStream::connect(addr).await.unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;

        let mut third = TcpStream::connect(addr).await.unwrap();
        third
            .write_all(format!("GET /metrics HTTP/1.1\r\nHost: x\r\n{CLOSE}\r\n").as_bytes())
            .await
            .unwrap();
        let mut buf = [0u8; 64];
        let early = tokio::time::timeout(Duration::from_millis(500), third.read(&mut buf)).await;
        assert!(early.is_err(), "served past the cap: {early:?}");

        // One hog leaves, so the waiting client gets its slot.
        drop(hog1);
        let reply = read_until_closed(&mut third, Duration::from_secs(3)).await;
        assert!(reply.starts_with(b"HTTP/1.1 200"), "{}", String::from_utf8_lossy(&reply));
        drop(hog2);
    }

    /// Collects formatted `tracing` output for one test.
    #[derive(Clone, Default)]
    struct Logs(Arc<Mutex<Vec<u8>>>);

    impl std::io::Write for Logs {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[tokio::test]
    async fn accept_errors_back_off_and_are_logged() {
        let logs = Logs::default();
        let sink = logs.clone();
        let subscriber =
            tracing_subscriber::fmt().with_writer(move || sink.clone()).with_ansi(false).finish();
        // The test runtime is single-threaded, so the server's tasks log here too.
        let _guard = tracing::subscriber::set_default(subscriber);

        let listener = Arc::new(TcpListener::bind("127.0.0.1:0").await.unwrap());
        let addr = listener.local_addr().unwrap();
        let calls = Arc::new(AtomicUsize::new(0));
        let (l, c) = (listener.clone(), calls.clone());
        let accept = move || {
            let (l, c) = (l.clone(), c.clone());
            async move {
                // As if the process were out of file descriptors three times.
                if c.fetch_add(1, Ordering::SeqCst) < 3 {
                    return Err(std::io::Error::from_raw_os_error(24));
                }
                l.accept().await
            }
        };
        let metrics: Arc<Metrics> = Arc::default();
        tokio::spawn(accept_loop(
            accept,
            router(metrics.registry(Gauges::default)),
            MetricsServerConfig::default(),
        ));

        let t = Instant::now();
        let (status, _, _) = request(addr, "GET", "/metrics", CLOSE).await;
        let waited = t.elapsed();
        assert_eq!(status, 200);
        // 100 + 200 + 400 ms of back-off, and no accept calls beyond those.
        assert!(waited >= Duration::from_millis(650), "{waited:?}");
        assert!(calls.load(Ordering::SeqCst) <= 5, "{} accept calls", calls.load(Ordering::SeqCst));
        let logs = String::from_utf8(logs.0.lock().unwrap().clone()).unwrap();
        assert_eq!(logs.matches("WARN").count(), 3, "{logs}");
        assert!(logs.contains("accept failed") && logs.contains("retrying in 400ms"), "{logs}");
    }
}
