//! The page's HTTP server (axum on a current-thread tokio runtime).
//!
//! Every request must name the bound address in `Host` — a page elsewhere that points its
//! own host name at 127.0.0.1 (DNS rebinding) is refused — and a request that carries an
//! `Origin` must come from the view's own page, so other sites cannot drive it either.
//!
//! | route | answer |
//! |---|---|
//! | `GET /` | the page (`page.html`, compiled in) |
//! | `GET /status?after=N` | the state as JSON, once its generation passes `N` (long poll, 20 s at most) |
//! | `GET /frame.png?channel=G` | the latest image's channel group `G` (default: the beauty) |
//! | `GET /pick?x=X&y=Y` | what is at pixel `(X, Y)`: prim, slot stack, channel values |
//! | `POST /camera` | a [`super::camera::Move`] as JSON |
//! | `POST /camera/select` | the Camera prim to look through (empty: the starting camera) |
//! | `POST /input` | set a material input in memory: `{"prim", "input", "type", "value"}` |
//! | `POST /slots` | mute or solo slots in memory: `{"muted": [..], "solo": null}` |
//! | `POST /camera/frame` | frame the picked prim |
//! | `POST /look/write` | write the input edits as an override layer beside the scene: `{"path"}` |

use super::Shared;
use super::look::InputEdit;
use super::worker::Command;
use super::{camera::Move, encode};
use crate::compose::slots::SlotFilter;
use axum::extract::{Query, Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use serde::Deserialize;
use serde_json::json;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

/// The page, served as it is.
const PAGE: &str = include_str!("page.html");

/// The longest a status request waits for something new.
const LONG_POLL: Duration = Duration::from_secs(20);

/// Serves `listener` until the process ends.
pub(crate) fn serve(listener: std::net::TcpListener, address: SocketAddr, shared: Arc<Shared>) -> Result<(), String> {
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().map_err(|e| e.to_string())?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::from_std(listener).map_err(|e| e.to_string())?;
        let allowed = Arc::new(Allowed { host: address.to_string(), origin: format!("http://{address}") });
        let app = axum::Router::new()
            .route("/", get(page))
            .route("/status", get(status))
            .route("/frame.png", get(frame))
            .route("/pick", get(pick))
            .route("/camera", post(camera))
            .route("/camera/select", post(select_camera))
            .route("/camera/frame", post(frame_selected))
            .route("/input", post(set_input))
            .route("/slots", post(set_slots))
            .route("/look/write", post(write_look))
            .with_state(shared)
            .layer(middleware::from_fn_with_state(allowed, guard));
        axum::serve(listener, app).await.map_err(|e| e.to_string())
    })
}

/// The `Host` and `Origin` a request may carry.
struct Allowed {
    host: String,
    origin: String,
}

async fn guard(State(allowed): State<Arc<Allowed>>, request: Request, next: Next) -> Response {
    let headers = request.headers();
    let host_ok = headers.get(header::HOST).is_some_and(|h| h.as_bytes() == allowed.host.as_bytes());
    let origin_ok = headers.get(header::ORIGIN).is_none_or(|o| o.as_bytes() == allowed.origin.as_bytes());
    if !host_ok || !origin_ok {
        let message = format!("refused: strata view answers only requests to {}\n", allowed.host);
        return (StatusCode::FORBIDDEN, message).into_response();
    }
    next.run(request).await
}

fn with_type(body: impl IntoResponse, content_type: &'static str) -> Response {
    let mut response = body.into_response();
    let headers = response.headers_mut();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    response
}

async fn page() -> Response {
    with_type(PAGE, "text/html; charset=utf-8")
}

#[derive(Deserialize)]
struct After {
    #[serde(default)]
    after: u64,
}

async fn status(State(shared): State<Arc<Shared>>, Query(q): Query<After>) -> Response {
    let mut generation = shared.generation.subscribe();
    let _ = tokio::time::timeout(LONG_POLL, generation.wait_for(|g| *g > q.after)).await;
    let body = shared.snapshot(|p| {
        let (image_width, image_height) = p.image.as_ref().map_or((0, 0), |i| (i.width, i.height));
        json!({
            "generation": p.generation,
            "samples": p.samples,
            "spp": p.spp,
            "width": p.width,
            "height": p.height,
            "image_width": image_width,
            "image_height": image_height,
            "channels": p.image.as_ref().map(|i| {
                let mut groups = encode::groups(i);
                if p.selected.is_some() && p.samples > 0 {
                    groups.extend(["CryptoObject", "CryptoMaterial"].map(|l| format!("{}{l}", encode::MATTE)));
                }
                if p.selected.is_some() {
                    let coverage = p.selected_layers.iter().enumerate();
                    groups.extend(coverage.map(|(i, slot)| format!("{}{i}:{slot}", encode::COVERAGE)));
                }
                groups
            }).unwrap_or_default(),
            "selected": p.selected.as_ref().map(|(prim, _)| prim),
            "diagnostics": p.diagnostics,
            "failed": p.failed,
            "edits": p.edits,
            "update_ms": p.update_ms,
            "cameras": p.cameras,
            "camera": p.camera,
            "watched": p.watched,
            "input_ms": p.input_ms,
            "slots": p.slots,
            "muted": p.muted,
            "solo": p.solo,
            "look_inputs": p.look_inputs,
            "samples_per_second": p.samples_per_second,
            "materials_compiled": p.materials_compiled,
            "parameter_writes": p.parameter_writes,
        })
    });
    with_type(body.to_string(), "application/json")
}

#[derive(Deserialize)]
struct Channel {
    channel: Option<String>,
}

async fn frame(State(shared): State<Arc<Shared>>, Query(q): Query<Channel>) -> Response {
    let Some((image, selected)) = shared.snapshot(|p| p.image.clone().map(|i| (i, p.selected.clone()))) else {
        return (StatusCode::NOT_FOUND, "no image yet\n").into_response();
    };
    let group = q.channel.unwrap_or_else(|| encode::BEAUTY.to_string());
    if let Some(rest) = group.strip_prefix(encode::COVERAGE) {
        let layer = rest.split(':').next().and_then(|i| i.parse().ok());
        let (reply, answer) = tokio::sync::oneshot::channel();
        if layer.is_none() || shared.commands.send(Command::Coverage { layer: layer.unwrap_or(0), reply }).is_err() {
            return (StatusCode::NOT_FOUND, "no such channel\n").into_response();
        }
        return match tokio::time::timeout(LONG_POLL, answer).await {
            Ok(Ok(Some(bytes))) => with_type(bytes, "image/png"),
            _ => (StatusCode::NOT_FOUND, "no such channel\n").into_response(),
        };
    }
    let encode = move || match (group.strip_prefix(encode::MATTE), selected) {
        (Some("CryptoObject"), Some((prim, _))) => encode::matte(&image, "CryptoObject", &prim),
        (Some("CryptoMaterial"), Some((_, material))) => encode::matte(&image, "CryptoMaterial", &material),
        (Some(_), _) => None,
        (None, _) => encode::png(&image, &group),
    };
    match tokio::task::spawn_blocking(encode).await {
        Ok(Some(bytes)) => with_type(bytes, "image/png"),
        _ => (StatusCode::NOT_FOUND, "no such channel\n").into_response(),
    }
}

#[derive(Deserialize)]
struct Pixel {
    x: usize,
    y: usize,
}

async fn pick(State(shared): State<Arc<Shared>>, Query(q): Query<Pixel>) -> Response {
    let (reply, answer) = tokio::sync::oneshot::channel();
    if shared.commands.send(Command::Pick { x: q.x, y: q.y, reply }).is_err() {
        return (StatusCode::SERVICE_UNAVAILABLE, "the renderer stopped\n").into_response();
    }
    match tokio::time::timeout(LONG_POLL, answer).await {
        Ok(Ok(json)) => with_type(json, "application/json"),
        _ => (StatusCode::SERVICE_UNAVAILABLE, "no answer from the renderer\n").into_response(),
    }
}

async fn camera(State(shared): State<Arc<Shared>>, body: String) -> Response {
    match serde_json::from_str::<Move>(&body) {
        Ok(m) => {
            let _ = shared.commands.send(Command::Camera(m));
            StatusCode::NO_CONTENT.into_response()
        }
        Err(e) => (StatusCode::BAD_REQUEST, format!("{e}\n")).into_response(),
    }
}

async fn select_camera(State(shared): State<Arc<Shared>>, body: String) -> Response {
    let path = body.trim();
    let _ = shared.commands.send(Command::SelectCamera((!path.is_empty()).then(|| path.to_string())));
    StatusCode::NO_CONTENT.into_response()
}

async fn frame_selected(State(shared): State<Arc<Shared>>) -> Response {
    let _ = shared.commands.send(Command::FrameSelected);
    StatusCode::NO_CONTENT.into_response()
}

async fn set_input(State(shared): State<Arc<Shared>>, body: String) -> Response {
    let at = std::time::Instant::now();
    let change = serde_json::from_str::<InputEdit>(&body).map_err(|e| e.to_string()).and_then(|e| e.change());
    match change {
        Ok(change) => {
            let _ = shared.commands.send(Command::SetInput { change, at });
            StatusCode::NO_CONTENT.into_response()
        }
        Err(e) => (StatusCode::BAD_REQUEST, format!("{e}\n")).into_response(),
    }
}

#[derive(Deserialize)]
struct Slots {
    #[serde(default)]
    muted: Vec<String>,
    solo: Option<String>,
}

async fn set_slots(State(shared): State<Arc<Shared>>, body: String) -> Response {
    match serde_json::from_str::<Slots>(&body) {
        Ok(slots) => {
            let filter = SlotFilter { muted: slots.muted.into_iter().collect(), solo: slots.solo };
            let _ = shared.commands.send(Command::Slots(filter));
            StatusCode::NO_CONTENT.into_response()
        }
        Err(e) => (StatusCode::BAD_REQUEST, format!("{e}\n")).into_response(),
    }
}

async fn write_look(State(shared): State<Arc<Shared>>) -> Response {
    let (reply, answer) = tokio::sync::oneshot::channel();
    if shared.commands.send(Command::WriteLook { reply }).is_err() {
        return (StatusCode::SERVICE_UNAVAILABLE, "the renderer stopped\n").into_response();
    }
    match tokio::time::timeout(LONG_POLL, answer).await {
        Ok(Ok(Ok(json))) => with_type(json, "application/json"),
        Ok(Ok(Err(e))) => (StatusCode::CONFLICT, format!("{e}\n")).into_response(),
        _ => (StatusCode::SERVICE_UNAVAILABLE, "no answer from the renderer\n").into_response(),
    }
}
