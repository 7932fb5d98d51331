//! The router: every route with its handler, body limit and token check, and the layers
//! around all of them (JSON errors, request logging). Which token a route needs is decided
//! here; `auth` only checks tokens.
//!
//! The user routes are registered from their handlers' OpenAPI descriptions
//! (`utoipa_axum::routes!`): a route's path and methods are written once, in the
//! `#[utoipa::path]` beside its handler, and both the router and the document served at
//! `/openapi.json` ([`document`]) are built from it, so the two cannot disagree.

use std::sync::OnceLock;
use std::time::Duration;

use axum::Router;
use axum::extract::DefaultBodyLimit;
use axum::routing::{get, post, put};
use tracing::error;
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::openapi::{InfoBuilder, LicenseBuilder, OpenApi, OpenApiBuilder, Tag};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use crate::handlers::{image, jobs, live, page, workers};
use crate::read_only::ReadOnly;
use crate::state::AppState;
use crate::tiling::protocol_limit;
use crate::{auth, error, metrics};

/// The user routes with their body limits and token checks, and their OpenAPI document.
fn user_routes(body_limit: usize) -> OpenApiRouter<AppState> {
    let job_routes = OpenApiRouter::new()
        .routes(routes!(jobs::list_jobs, jobs::submit))
        .routes(routes!(jobs::get_job, jobs::delete_job, jobs::patch_job))
        .routes(routes!(jobs::retry_job))
        .layer(DefaultBodyLimit::max(body_limit))
        .route_layer(axum::middleware::from_fn(move |req, next| {
            error::declared_length_within(body_limit, req, next)
        }));
    OpenApiRouter::with_openapi(base_document())
        .merge(job_routes)
        .routes(routes!(image::image))
        .routes(routes!(live::preview))
        .routes(routes!(live::events))
        .routes(routes!(live::tiles))
        .routes(routes!(live::scene))
        .routes(routes!(page::healthz))
        .routes(routes!(page::scrape_metrics))
        .routes(routes!(workers::list_workers))
        .routes(routes!(page::page))
        .routes(routes!(page::api_page))
        .routes(routes!(page::openapi))
}

/// The document's own parts: what the service is, and the schemes of its tokens.
fn base_document() -> OpenApi {
    let mut doc = OpenApiBuilder::new()
        .info(
            InfoBuilder::new()
                .title("Tessera")
                .version(env!("CARGO_PKG_VERSION"))
                .description(Some(
                    "A distributed ray-tracing farm: submit a `.ray` scene, watch its tiles \
                     render, download the PNG. Routes that change jobs need the submit token \
                     when the service is started with one (`Authorization: Bearer <token>`), \
                     and reads need the read token when it has one. \
                     Every error answer is JSON `{\"error\": \"...\"}` with a fitting status.",
                ))
                .license(Some(
                    LicenseBuilder::new().name("MIT OR Apache-2.0").build(),
                ))
                .build(),
        )
        .tags(Some([
            Tag::new("jobs"),
            Tag::new("service"),
            Tag::new("pages"),
        ]))
        .build();
    let bearer = |about: &str| {
        SecurityScheme::Http(
            HttpBuilder::new()
                .scheme(HttpAuthScheme::Bearer)
                .description(Some(about))
                .build(),
        )
    };
    let components = doc.components.get_or_insert_with(Default::default);
    components.add_security_scheme(
        "submit_token",
        bearer("The service's `--submit-token`, for routes that change jobs, when it has one."),
    );
    components.add_security_scheme(
        "read_token",
        bearer(
            "The service's `--read-token` (or its submit token), for reads, when it has one. \
             The pages send it as the `tessera_token` cookie instead.",
        ),
    );
    doc
}

/// Declares the read token on every read that `--read-token` guards (each `GET` but
/// [`auth::OPEN_READS`]): optional, as it is until the service is started with one.
fn declare_read_token(doc: &mut OpenApi) {
    use utoipa::openapi::security::SecurityRequirement;
    for (path, item) in doc.paths.paths.iter_mut() {
        if auth::OPEN_READS.contains(&path.as_str()) {
            continue;
        }
        if let Some(op) = item.get.as_mut() {
            op.security = Some(vec![
                SecurityRequirement::default(),
                SecurityRequirement::new("read_token", Vec::<String>::new()),
            ]);
        }
    }
}

/// Links the job a submission answers to the routes of one job (`id` from the answer's
/// body), so that a client generator or a stateful test can follow them.
fn link_submission(doc: &mut OpenApi) {
    use utoipa::openapi::RefOr;
    use utoipa::openapi::link::LinkBuilder;
    let targets: Vec<(String, String)> = doc
        .paths
        .paths
        .iter()
        .filter(|(path, _)| path.starts_with("/jobs/{id}"))
        .flat_map(|(_, item)| {
            [&item.get, &item.post, &item.delete, &item.patch]
                .into_iter()
                .filter_map(|op| op.as_ref()?.operation_id.clone())
                .collect::<Vec<_>>()
        })
        .map(|id| (id.clone(), id))
        .collect();
    let Some(created) = doc
        .paths
        .paths
        .get_mut("/jobs")
        .and_then(|item| item.post.as_mut())
        .and_then(|op| op.responses.responses.get_mut("201"))
    else {
        return;
    };
    if let RefOr::T(created) = created {
        for (name, operation) in targets {
            let link = LinkBuilder::new()
                .operation_id(operation)
                .parameter("id", "$response.body#/id")
                .build();
            created.links.insert(name, RefOr::T(link));
        }
    }
}

/// A small scene the document gives as the example of a submission's body, so that a
/// reader (or a generated test) has one that renders.
const EXAMPLE_SCENE: &str = "[GLOBALS]\nwidth = 64\nheight = 48\n[/GLOBALS]\n[CAMERA]\n\
eye = <0, 2, 10>\n[/CAMERA]\n[LIGHT]\nposition = <10, 10, 10>\n[/LIGHT]\n[OBJECT]\n\
type = sphere\nradius = 2\ncolor1 = <0.9, 0.3, 0.2>\n[/OBJECT]\n";

/// Sets [`EXAMPLE_SCENE`] as the example of `POST /jobs`'s text bodies.
fn example_scene(doc: &mut OpenApi) {
    let Some(body) = doc
        .paths
        .paths
        .get_mut("/jobs")
        .and_then(|item| item.post.as_mut())
        .and_then(|op| op.request_body.as_mut())
    else {
        return;
    };
    let utoipa::openapi::RefOr::T(body) = body else {
        return;
    };
    for kind in ["text/plain", "application/octet-stream"] {
        if let Some(utoipa::openapi::RefOr::T(content)) = body.content.get_mut(kind) {
            content.example = Some(serde_json::Value::String(EXAMPLE_SCENE.to_string()));
        }
    }
}

/// The OpenAPI 3.1 document of the user routes, as JSON (built once).
pub fn document() -> &'static str {
    static DOC: OnceLock<String> = OnceLock::new();
    DOC.get_or_init(|| {
        let mut doc = user_routes(0).into_openapi();
        link_submission(&mut doc);
        example_scene(&mut doc);
        declare_read_token(&mut doc);
        // Serializing a document of strings and numbers cannot fail.
        doc.to_pretty_json()
            .unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    })
}

/// All routes, with their body limits and token checks.
pub fn router(state: AppState) -> Router {
    // A tile blob: the header and at most `MAX_TILE` × `MAX_TILE` RGB pixels.
    let tile_limit = protocol_limit();
    let body_limit = state.cfg.max_body_bytes;
    let worker_routes = Router::new()
        .route("/worker/claim", post(workers::claim))
        .route("/worker/jobs/{id}", get(workers::job))
        .route("/worker/jobs/{id}/assets/{name}", get(workers::asset))
        .route("/worker/jobs/{id}/tiles/{idx}", put(workers::result))
        .route("/worker/jobs/{id}/tiles/{idx}/renew", post(workers::renew))
        .route("/worker/jobs/{id}/tiles/{idx}/fail", post(workers::fail))
        .route(
            "/worker/jobs/{id}/tiles/{idx}/release",
            post(workers::release),
        )
        .route("/worker/bye", post(workers::bye))
        .layer(DefaultBodyLimit::max(tile_limit))
        .route_layer(axum::middleware::from_fn(move |req, next| {
            error::declared_length_within(tile_limit, req, next)
        }))
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            refuse_writes,
        ))
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_worker_token,
        ));
    let (user_routes, _) = user_routes(body_limit).split_for_parts();
    // The submit token guards every user route but reads (`auth` lets `GET`s through);
    // a service started without room to write refuses writes once the token is checked.
    let user_routes = user_routes
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            refuse_writes,
        ))
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_submit_token,
        ));
    Router::new()
        .route("/static/{file}", get(page::asset))
        .route("/favicon.ico", get(page::favicon))
        .merge(user_routes)
        .merge(worker_routes)
        .layer(axum::Extension(page::Document(document())))
        .layer(axum::middleware::from_fn(metrics::count_requests))
        .fallback(error::no_route)
        .method_not_allowed_fallback(error::wrong_method)
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_read_token,
        ))
        .layer(axum::middleware::from_fn(error::json_errors))
        .layer(axum::middleware::from_fn(security_headers))
        .layer(tower_http::trace::TraceLayer::new_for_http().on_failure(log_failure))
        .with_state(state)
}

/// While the service is read-only (it started without room to write), every request but a
/// read (`GET`, `HEAD`) is answered `503` with `Retry-After`, before its handler runs.
async fn refuse_writes(
    axum::extract::State(state): axum::extract::State<AppState>,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::http::Method;
    use axum::response::IntoResponse;
    if matches!(*req.method(), Method::GET | Method::HEAD) {
        return next.run(req).await;
    }
    match state.read_only.why() {
        Some(why) => ReadOnly::refusal(&why).into_response(),
        None => next.run(req).await,
    }
}

/// The policy of every answer: the pages load their scripts, styles and icon from
/// `/static/` only (they have no inline script or style), images from here or a preview's
/// `blob:` URL, and talk to this service only; nothing may frame them.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'self'; \
     style-src 'self'; img-src 'self' blob:; connect-src 'self'; base-uri 'none'; \
     form-action 'self'; frame-ancestors 'none'";

/// Adds to every answer: `X-Content-Type-Options: nosniff` (a scene or an error is never
/// taken for a script or a page), `Referrer-Policy: no-referrer` (job URLs stay here) and
/// [`CONTENT_SECURITY_POLICY`].
async fn security_headers(
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::http::{HeaderValue, header};
    let mut resp = next.run(req).await;
    let h = resp.headers_mut();
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CONTENT_SECURITY_POLICY),
    );
    resp
}

/// tower-http's log line for a failed response: an error, except a `503`, which the
/// service answers on purpose (a busy database, a farm paused for a full disk, a
/// submission waiting for room: each logged where it is decided) and which comes once per
/// waiting worker's claim while the farm is paused: logged at DEBUG.
fn log_failure(
    class: tower_http::classify::ServerErrorsFailureClass,
    latency: Duration,
    _span: &tracing::Span,
) {
    use tower_http::classify::ServerErrorsFailureClass::StatusCode as Status;
    let ms = latency.as_millis() as u64;
    match class {
        Status(s) if s == axum::http::StatusCode::SERVICE_UNAVAILABLE => {
            tracing::debug!(ms, "answered 503")
        }
        other => error!(ms, "response failed: {other}"),
    }
}
