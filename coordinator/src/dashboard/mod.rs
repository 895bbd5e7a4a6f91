//! The farm's web page (`sylva coordinator --http ADDR`): jobs, workers and
//! the frame being rendered, live. Plain HTML, CSS and JavaScript compiled
//! into the binary (`index.html`, `app.js`, `style.css` beside this file),
//! a JSON API over the same gRPC service methods the command line calls
//! (list, cancel, requeue, priority, results to download), and server-sent
//! events that push a snapshot twice a second.
//!
//! Access: where the coordinator has a token, reading needs it too (as
//! `Authorization: Bearer …` or the `sylva_token` cookie the page sets, since
//! an `EventSource` or an `<img>` cannot send headers); changing anything
//! (cancel, requeue, priority) needs the header, which another site's form cannot
//! send, so a page elsewhere cannot act with the cookie. Without a token the
//! page serves this machine only: the command line binds it to loopback,
//! and a request whose `Host` is not a loopback name (DNS rebinding) or
//! whose `Origin` is another site's is refused. Every change takes JSON.

use crate::access::Caller;
use crate::job_state::{wire_ended, wire_name};
use crate::service::CoordinatorService;
use axum::Router;
use axum::extract::{Path, RawQuery, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::sse::{Event, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use serde_json::{Value, json};
use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;
use sylva_proto::pb;
use sylva_proto::pb::coordinator_server::Coordinator;
use sylva_proto::sync::lock;
use tonic::Request;

const INDEX: &str = include_str!("index.html");
const APP: &str = include_str!("app.js");
const STYLE: &str = include_str!("style.css");
/// How often the event stream sends a snapshot.
const TICK: Duration = Duration::from_millis(500);

/// Starts serving the dashboard of `service` on `listener` until
/// `shutdown`. Without a token anyone who reaches the page could cancel
/// jobs, so a coordinator without one serves it on a loopback address only.
pub fn start(
    listener: tokio::net::TcpListener,
    service: &CoordinatorService,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<tokio::task::JoinHandle<()>> {
    let addr = listener.local_addr()?;
    if !service.needs_token() && !addr.ip().is_loopback() {
        anyhow::bail!(
            "--http {addr}: without a token the dashboard serves this machine only (anyone who reaches it could cancel jobs); give --http 127.0.0.1:PORT, or a token (--token-file, or users: sylva token add)"
        );
    }
    let app = router(service.clone());
    Ok(tokio::spawn(async move {
        tokio::select! {
            () = crate::metrics::serve_app(listener, app) => {}
            () = shutdown => {}
        }
    }))
}

/// The page's routes.
pub fn router(service: CoordinatorService) -> Router {
    Router::new()
        .route("/", get(|| async { ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], INDEX) }))
        .route(
            "/app.js",
            get(|| async { ([(header::CONTENT_TYPE, "text/javascript; charset=utf-8")], APP) }),
        )
        .route(
            "/style.css",
            get(|| async { ([(header::CONTENT_TYPE, "text/css; charset=utf-8")], STYLE) }),
        )
        .route("/api/snapshot", get(snapshot_route))
        .route("/api/events", get(events))
        .route("/api/jobs/{id}/live", get(live))
        .route("/api/jobs/{id}/preview.png", get(preview))
        .route("/api/jobs/{id}/result/{format}", get(download))
        .route("/api/jobs/{id}/cancel", post(cancel))
        .route("/api/jobs/{id}/requeue", post(requeue))
        .route("/api/jobs/{id}/priority", post(priority))
        .layer(axum::middleware::from_fn_with_state(service.clone(), guard))
        .with_state(service)
}

/// Refuses a request another site made or aimed here: a change whose
/// `Origin` is not this page's; and, with no token to protect the farm,
/// any request whose `Host` is not a loopback name (a DNS-rebinding page
/// reaches this server under its own name) or whose `Origin` is another
/// site's.
async fn guard(
    State(service): State<CoordinatorService>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let headers = request.headers();
    let host = headers.get(header::HOST).and_then(|v| v.to_str().ok()).unwrap_or("");
    let open = !service.needs_token();
    if open && !loopback_host(host) {
        return (
            StatusCode::MISDIRECTED_REQUEST,
            "without a token this dashboard answers only to this machine's own names (localhost, 127.0.0.1, [::1])",
        )
            .into_response();
    }
    let change = !matches!(*request.method(), axum::http::Method::GET | axum::http::Method::HEAD);
    if let Some(origin) = headers.get(header::ORIGIN).map(|v| v.to_str().unwrap_or("?"))
        && (change || open)
        && !same_origin(origin, host)
    {
        return (StatusCode::FORBIDDEN, "a request from another site changes nothing here")
            .into_response();
    }
    next.run(request).await
}

/// Whether `host` (a `Host` header: a name and maybe a port) names this machine.
fn loopback_host(host: &str) -> bool {
    let name = match host.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or(""),
        None => host.rsplit_once(':').map_or(host, |(n, _)| n),
    };
    name.eq_ignore_ascii_case("localhost")
        || name.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

/// Whether a request's `Origin` is the page this server serves at `host`.
fn same_origin(origin: &str, host: &str) -> bool {
    ["http://", "https://"]
        .iter()
        .any(|scheme| origin.strip_prefix(scheme).is_some_and(|h| h.eq_ignore_ascii_case(host)))
}

/// The bearer token of a request: its header, or (`cookie_too`) its cookie.
fn token(headers: &HeaderMap, cookie_too: bool) -> Option<String> {
    let bearer = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().split_once(' '))
        .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
        .map(|(_, t)| t.trim().to_string());
    let cookie = || {
        headers
            .get_all(header::COOKIE)
            .iter()
            .filter_map(|v| v.to_str().ok())
            .flat_map(|v| v.split(';'))
            .find_map(|c| {
                let (k, v) = c.trim().split_once('=')?;
                (k == "sylva_token").then(|| percent_decode(v))
            })
    };
    bearer.or_else(|| if cookie_too { cookie() } else { None })
}

/// `%XX` escapes of a cookie value undone (the page writes it with encodeURIComponent).
fn percent_decode(v: &str) -> String {
    let b = v.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && i + 2 < b.len()
            && let Ok(x) =
                u8::from_str_radix(std::str::from_utf8(&b[i + 1..i + 3]).unwrap_or("zz"), 16)
        {
            out.push(x);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The caller of a job's page, who must be one who may watch jobs (an
/// admin or a submitter, as gRPC's `WatchJob` asks): a worker's token is
/// refused before any job id is looked up, so it learns nothing of them.
fn viewer(service: &CoordinatorService, headers: &HeaderMap) -> Result<Caller, Box<Response>> {
    let caller =
        service.caller_of(token(headers, true).as_deref()).ok_or_else(|| Box::new(refused()))?;
    if !matches!(caller.role, crate::access::Role::Admin | crate::access::Role::Submitter) {
        let why = format!("a {} token cannot watch jobs", caller.role.name());
        return Err(Box::new((StatusCode::FORBIDDEN, why).into_response()));
    }
    Ok(caller)
}

fn refused() -> Response {
    (StatusCode::UNAUTHORIZED, "this coordinator needs its token: enter it at the top of the page")
        .into_response()
}

fn status_response(s: tonic::Status) -> Response {
    let code = match s.code() {
        tonic::Code::NotFound => StatusCode::NOT_FOUND,
        tonic::Code::InvalidArgument => StatusCode::BAD_REQUEST,
        tonic::Code::FailedPrecondition => StatusCode::CONFLICT,
        tonic::Code::PermissionDenied => StatusCode::FORBIDDEN,
        tonic::Code::Unauthenticated => StatusCode::UNAUTHORIZED,
        tonic::Code::OutOfRange => StatusCode::NOT_FOUND,
        tonic::Code::ResourceExhausted => StatusCode::INSUFFICIENT_STORAGE,
        tonic::Code::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
        _ => StatusCode::INTERNAL_SERVER_ERROR,
    };
    (code, s.message().to_string()).into_response()
}

/// A request to the service as `caller` makes it.
fn by<T>(caller: &Caller, message: T) -> Request<T> {
    let mut r = Request::new(message);
    r.extensions_mut().insert(caller.clone());
    r
}

/// Jobs and workers as the page lists them.
async fn snapshot(service: &CoordinatorService, caller: &Caller) -> Value {
    let list = service
        .list_jobs(by(caller, pb::ListJobsRequest {}))
        .await
        .map(|r| r.into_inner())
        .unwrap_or_default();
    let jobs = list.jobs;
    let workers = service
        .list_workers(by(caller, pb::ListWorkersRequest {}))
        .await
        .map(|r| r.into_inner().workers)
        .unwrap_or_default();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0);
    json!({
        "now_unix_ms": now,
        "needs_token": service.needs_token(),
        "store_problem": list.store_problem,
        "jobs": jobs.iter().map(|j| json!({
            "id": j.id, "name": j.name, "state": wire_name(j.state), "priority": j.priority,
            "strips_done": j.strips_done, "strips_total": j.strips_total, "retries": j.retries,
            "frames": j.frames, "frames_done": j.frames_done,
            "submitter": j.submitter, "error": j.error, "ended": wire_ended(j.state),
            "submitted_unix_ms": j.submitted_unix_ms, "started_unix_ms": j.started_unix_ms, "finished_unix_ms": j.finished_unix_ms,
            "stage": j.stage, "eta_ms": j.eta_ms, "requeueable": crate::job_state::JobState::from_wire(j.state).is_some_and(|s| s.requeueable()),
        })).collect::<Vec<_>>(),
        "workers": workers.iter().map(|w| json!({
            "addr": w.addr, "adapter": w.adapter, "alive": w.alive, "busy_strips": w.busy_strips,
            "strips_done": w.strips_done, "strips_failed": w.strips_failed, "cached_scenes": w.cached_scenes,
            "gpu_memory_bytes": w.gpu_memory_bytes,
            "ray_queries": w.ray_queries, "backend": w.backend, "backend_why": w.backend_why,
        })).collect::<Vec<_>>(),
    })
}

async fn snapshot_route(State(service): State<CoordinatorService>, headers: HeaderMap) -> Response {
    let Some(caller) = service.caller_of(token(&headers, true).as_deref()) else {
        return refused();
    };
    axum::Json(snapshot(&service, &caller).await).into_response()
}

/// Event streams one client address may hold open at once.
pub const STREAMS_PER_CLIENT: usize = 4;
/// An event stream ends after this long; the page's `EventSource` opens
/// another at once, so only a client that stopped listening is let go.
pub const STREAM_LIFETIME: Duration = Duration::from_secs(600);
/// A stream whose client has not taken an event for this long (its
/// socket full: it stopped reading) is closed.
pub const STREAM_UNREAD: Duration = Duration::from_secs(10);

/// Open event streams per client address.
static STREAMS: std::sync::LazyLock<crate::metrics::ClientCounts> =
    std::sync::LazyLock::new(Default::default);

/// A snapshot now and every [`TICK`] after, as `snapshot` events, for at
/// most [`STREAM_LIFETIME`]; at most [`STREAMS_PER_CLIENT`] per client, and
/// a stream its client stops reading is closed after [`STREAM_UNREAD`].
async fn events(
    State(service): State<CoordinatorService>,
    connection: Option<axum::Extension<crate::metrics::Connection>>,
    headers: HeaderMap,
) -> Response {
    let Some(caller) = service.caller_of(token(&headers, true).as_deref()) else {
        return refused();
    };
    let ip = connection.as_ref().map_or(std::net::Ipv4Addr::UNSPECIFIED.into(), |c| c.peer.ip());
    let Some(slot) = STREAMS.take(ip, STREAMS_PER_CLIENT) else {
        return (
            StatusCode::TOO_MANY_REQUESTS,
            format!("at most {STREAMS_PER_CLIENT} event streams per client: close a page first"),
        )
            .into_response();
    };
    // The time an event was last taken, and a watchdog that closes the
    // connection when the client stops taking them (hyper then stops
    // polling this stream, so the stream itself cannot notice).
    let taken = Arc::new(std::sync::Mutex::new(std::time::Instant::now()));
    if let Some(axum::Extension(c)) = connection {
        let (taken, close) = (taken.clone(), c.close.clone());
        tokio::spawn(async move {
            loop {
                tokio::time::sleep(TICK).await;
                let last = *lock(&taken);
                if Arc::strong_count(&taken) == 1 {
                    return; // the stream ended
                }
                if last.elapsed() > STREAM_UNREAD {
                    close.notify_one();
                    return;
                }
            }
        });
    }
    let until = std::time::Instant::now() + STREAM_LIFETIME;
    let stream =
        futures_util::stream::unfold((service, true, slot), move |(service, first, slot)| {
            let (taken, caller) = (taken.clone(), caller.clone());
            async move {
                if !first {
                    tokio::time::sleep(TICK).await;
                }
                if std::time::Instant::now() > until {
                    return None;
                }
                *lock(&taken) = std::time::Instant::now();
                let data = snapshot(&service, &caller).await.to_string();
                let event = Event::default().event("snapshot").data(data);
                Some((Ok::<_, Infallible>(event), (service, false, slot)))
            }
        });
    // A snapshot every tick keeps the connection busy: no keep-alive comments needed.
    Sse::new(stream).into_response()
}

/// A job's strips: which worker rendered which columns, in what time, and
/// which failed where; with the per-column cost they imply.
async fn live(
    State(service): State<CoordinatorService>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Response {
    if let Err(r) = viewer(&service, &headers) {
        return *r;
    }
    let Some(f) = service.live(&id) else {
        return (StatusCode::NOT_FOUND, "no such job").into_response();
    };
    let mut cost = vec![0.0f64; f.width as usize];
    for s in f.strips.iter().filter(|s| s.error.is_empty() && s.x1 > s.x0) {
        let per = s.ms / (s.x1 - s.x0) as f64;
        for c in cost.iter_mut().take(s.x1 as usize).skip(s.x0 as usize) {
            *c = per;
        }
    }
    axum::Json(
        json!({ "width": f.width, "height": f.height, "strips": f.strips, "column_ms": cost }),
    )
    .into_response()
}

/// The frame so far (black where no strip has come back), or the finished image.
async fn preview(
    State(service): State<CoordinatorService>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Response {
    let caller = match viewer(&service, &headers) {
        Ok(c) => c,
        Err(r) => return *r,
    };
    let Some(f) = service.live(&id) else {
        return (StatusCode::NOT_FOUND, "no such job").into_response();
    };
    let png = if f.preview.is_empty() {
        match service
            .fetch_result(by(
                &caller,
                pb::FetchRequest { id: id.clone(), format: "png".into(), frame: f.frame as u32 },
            ))
            .await
        {
            Ok(r) => r.into_inner().data,
            Err(s) => return status_response(s),
        }
    } else {
        let Some(img) = image::RgbImage::from_raw(f.width, f.height, f.preview) else {
            return StatusCode::INTERNAL_SERVER_ERROR.into_response();
        };
        let mut out = std::io::Cursor::new(Vec::new());
        if img.write_to(&mut out, image::ImageFormat::Png).is_err() {
            return StatusCode::INTERNAL_SERVER_ERROR.into_response();
        }
        out.into_inner()
    };
    ([(header::CONTENT_TYPE, "image/png"), (header::CACHE_CONTROL, "no-store")], png)
        .into_response()
}

/// A finished job's image as a file to keep: `format` is `png` or `exr`,
/// `?frame=N` picks a sequence's frame (the first by default).
async fn download(
    State(service): State<CoordinatorService>,
    headers: HeaderMap,
    Path((id, format)): Path<(String, String)>,
    RawQuery(query): RawQuery,
) -> Response {
    let caller = match viewer(&service, &headers) {
        Ok(c) => c,
        Err(r) => return *r,
    };
    let (kind, ext) = match format.as_str() {
        "png" => ("image/png", "png"),
        "exr" => ("image/x-exr", "exr"),
        _ => return (StatusCode::NOT_FOUND, "results are png or exr").into_response(),
    };
    let frame = query.as_deref().unwrap_or("").split('&').find_map(|kv| kv.strip_prefix("frame="));
    let Ok(frame) = frame.map_or(Ok(0), str::parse::<u32>) else {
        return (StatusCode::BAD_REQUEST, "?frame= takes a frame number from 0").into_response();
    };
    let request = pb::FetchRequest { id: id.clone(), format: ext.into(), frame };
    match service.fetch_result(by(&caller, request)).await {
        // The id is one the coordinator knows (the fetch found it): a
        // plain name, safe in a header.
        Ok(r) => (
            [
                (header::CONTENT_TYPE, kind.to_string()),
                (
                    header::CONTENT_DISPOSITION,
                    format!("attachment; filename=\"{id}-{frame:04}.{ext}\""),
                ),
                (header::CACHE_CONTROL, "no-store".to_string()),
            ],
            r.into_inner().data,
        )
            .into_response(),
        Err(s) => status_response(s),
    }
}

/// Whether a request that changes the farm says it is JSON. A form on
/// another site can post only text/plain or a form encoding without the
/// browser asking this server first (a CORS preflight it never answers),
/// so a write in any other type is refused, token or not.
fn json_write(headers: &HeaderMap) -> bool {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .is_some_and(|t| t.trim().eq_ignore_ascii_case("application/json"))
}

/// The caller of a change: one that says it is JSON (else 415) and brings
/// the token in its header, not the cookie (else 401).
fn writer(service: &CoordinatorService, headers: &HeaderMap) -> Result<Caller, Box<Response>> {
    if !json_write(headers) {
        let why = "changes take Content-Type: application/json";
        return Err(Box::new((StatusCode::UNSUPPORTED_MEDIA_TYPE, why).into_response()));
    }
    service.caller_of(token(headers, false).as_deref()).ok_or_else(|| Box::new(refused()))
}

async fn cancel(
    State(service): State<CoordinatorService>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Response {
    let caller = match writer(&service, &headers) {
        Ok(c) => c,
        Err(r) => return *r,
    };
    match service.cancel_job(by(&caller, pb::JobId { id })).await {
        Ok(r) => axum::Json(json!({ "id": r.get_ref().id, "state": wire_name(r.get_ref().state) }))
            .into_response(),
        Err(s) => status_response(s),
    }
}

async fn requeue(
    State(service): State<CoordinatorService>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Response {
    let caller = match writer(&service, &headers) {
        Ok(c) => c,
        Err(r) => return *r,
    };
    match service.requeue_job(by(&caller, pb::JobId { id: id.clone() })).await {
        Ok(r) => axum::Json(json!({ "id": r.get_ref().id, "requeued": id })).into_response(),
        Err(s) => status_response(s),
    }
}

async fn priority(
    State(service): State<CoordinatorService>,
    headers: HeaderMap,
    Path(id): Path<String>,
    body: String,
) -> Response {
    let caller = match writer(&service, &headers) {
        Ok(c) => c,
        Err(r) => return *r,
    };
    let Some(p) = serde_json::from_str::<Value>(&body)
        .ok()
        .and_then(|v| v.get("priority")?.as_i64())
        .and_then(|p| i32::try_from(p).ok())
    else {
        return (StatusCode::BAD_REQUEST, "send {\"priority\": N}").into_response();
    };
    match service.set_priority(by(&caller, pb::SetPriorityRequest { id, priority: p })).await {
        Ok(r) => axum::Json(json!({ "id": r.get_ref().id, "priority": r.get_ref().priority }))
            .into_response(),
        Err(s) => status_response(s),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_token_comes_from_the_header_or_for_reading_the_cookie() {
        let mut h = HeaderMap::new();
        h.insert(header::COOKIE, "a=b; sylva_token=s%3Acret".parse().unwrap());
        assert_eq!(token(&h, true).as_deref(), Some("s:cret"));
        assert_eq!(token(&h, false), None, "a cookie does not authorise a change");
        h.insert(header::AUTHORIZATION, "Bearer abc".parse().unwrap());
        assert_eq!(token(&h, false).as_deref(), Some("abc"));
    }

    #[test]
    fn only_this_machines_names_and_this_pages_origin_pass() {
        for h in ["localhost:8080", "127.0.0.1:80", "127.1.2.3", "[::1]:8080", "LOCALHOST"] {
            assert!(loopback_host(h), "{h}");
        }
        for h in ["evil.example:8080", "10.0.0.1:80", "", "localhost.evil.example", "[::2]:1"] {
            assert!(!loopback_host(h), "{h}");
        }
        assert!(same_origin("http://127.0.0.1:8080", "127.0.0.1:8080"));
        assert!(!same_origin("http://evil.example", "127.0.0.1:8080"));
        assert!(!same_origin("null", "127.0.0.1:8080"));
    }

    #[test]
    fn only_json_changes_the_farm() {
        let mut h = HeaderMap::new();
        assert!(!json_write(&h), "no type");
        for (t, ok) in [
            ("application/json", true),
            ("Application/JSON; charset=utf-8", true),
            ("text/plain", false),
            ("application/x-www-form-urlencoded", false),
            ("multipart/form-data; boundary=x", false),
        ] {
            h.insert(header::CONTENT_TYPE, t.parse().unwrap());
            assert_eq!(json_write(&h), ok, "{t}");
        }
    }
}
