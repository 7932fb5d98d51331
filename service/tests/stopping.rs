//! A stopping service answers the requests that wait: a graceful stop waits for every open
//! request, and a client's `GET /jobs/{id}?wait=60` or a worker's long claim must not hold it
//! for their whole wait (longer than `docker stop` gives before its kill).

use std::time::Duration;

use axum::extract::{Json, Path, Query, State};
use axum::http::StatusCode;
use axum::response::IntoResponse;
use tessera_protocol::ClaimRequest;
use tessera_service::store::{NewJob, Store};
use tessera_service::{AppState, ClaimParams, Config, claim, get_job, submit};
use tessera_tracer::tiles;
use tokio::sync::watch;

async fn state(stopping: watch::Receiver<bool>) -> AppState {
    state_with(Config::defaults(), stopping).await
}

async fn state_with(cfg: Config, stopping: watch::Receiver<bool>) -> AppState {
    let store = Store::open("sqlite::memory:")
        .await
        .expect("in-memory queue");
    AppState::new(cfg, store, stopping)
}

/// A multipart submission of `scene` and PNG textures `t0.png`, `t1.png`, … of the given
/// sizes.
fn textured(scene: &str, sizes: &[(u32, u32)]) -> axum::extract::Request {
    let mut body = Vec::new();
    body.extend_from_slice(b"--XyZ\r\nContent-Disposition: form-data; name=\"scene\"\r\n\r\n");
    body.extend_from_slice(scene.as_bytes());
    for (i, &(w, h)) in sizes.iter().enumerate() {
        let png = tessera_tracer::encode_png(w, h, &vec![9u8; (w * h * 3) as usize]).expect("png");
        body.extend_from_slice(
            format!(
                "\r\n--XyZ\r\nContent-Disposition: form-data; name=\"asset\"; \
                 filename=\"t{i}.png\"\r\n\r\n"
            )
            .as_bytes(),
        );
        body.extend_from_slice(&png);
    }
    body.extend_from_slice(b"\r\n--XyZ--\r\n");
    axum::http::Request::post("/jobs")
        .header("content-type", "multipart/form-data; boundary=XyZ")
        .header("content-length", body.len())
        .body(axum::body::Body::from(body))
        .expect("a request")
}

/// Checks that `waiting` (a handler's task) is still waiting, stops the service, and returns
/// its answer, which must come far sooner than the handler's own wait would end: from the
/// stop, not from a timeout.
async fn answer_on_stop<T>(
    stop: watch::Sender<bool>,
    mut waiting: tokio::task::JoinHandle<T>,
) -> T {
    assert!(
        tokio::time::timeout(Duration::from_millis(100), &mut waiting)
            .await
            .is_err(),
        "still waiting"
    );
    stop.send(true).expect("a receiver");
    tokio::time::timeout(Duration::from_secs(5), waiting)
        .await
        .expect("answered once the service stops")
        .expect("no panic")
}

#[tokio::test]
async fn a_waiting_job_request_answers_when_the_service_stops() {
    let (stop, stopping) = watch::channel(false);
    let state = state(stopping).await;
    let rects = tiles(64, 64, 32);
    let job = NewJob {
        id: "waited".into(),
        scene: "[GLOBALS]\n[/GLOBALS]\n".into(),
        name: None,
        width: 64,
        height: 64,
        tile: 32,
        sampler: None,
        samples: None,
        threshold: None,
        created_at: 0,
        priority: 0,
    };
    state
        .store
        .insert_job(&job, &rects, &[])
        .await
        .expect("job");
    // Nothing renders the job, so the request waits.
    let wait = tokio::spawn(get_job(
        State(state.clone()),
        Path("waited".to_string()),
        axum::http::HeaderMap::new(),
        "/jobs/waited?wait=60".parse().expect("a URI"),
    ));
    let answer = answer_on_stop(stop, wait).await.expect("the job");
    let body = axum::body::to_bytes(answer.into_body(), 1 << 20)
        .await
        .expect("the body");
    let job: serde_json::Value = serde_json::from_slice(&body).expect("JSON");
    assert_eq!(job["state"], "queued", "the job as it is");
}

#[tokio::test]
async fn a_waiting_claim_answers_no_work_when_the_service_stops() {
    let (stop, stopping) = watch::channel(false);
    let state = state(stopping).await;
    // No job at all: the claim waits for work.
    let waiting = tokio::spawn(claim(
        State(state.clone()),
        Query(ClaimParams {
            wait_ms: Some(10_000),
        }),
        Json(ClaimRequest::by("w")),
    ));
    let answer = answer_on_stop(stop, waiting).await.expect("an answer");
    assert_eq!(answer.into_response().status(), StatusCode::NO_CONTENT);
}

/// A submission waiting for room to be received (`--max-receiving-bytes`) is answered `503`
/// when the service stops, instead of holding the stop up for the rest of its wait.
#[tokio::test]
async fn a_submission_waiting_for_room_answers_when_the_service_stops() {
    let (stop, stopping) = watch::channel(false);
    let state = state(stopping).await;
    let mut held = state.receiving.hold();
    held.grow(u64::MAX, Duration::from_secs(1))
        .await
        .expect("the whole budget");
    let scene = "[GLOBALS]\n[/GLOBALS]\n";
    let req = axum::http::Request::post("/jobs")
        .header("content-length", scene.len())
        .body(axum::body::Body::from(scene))
        .expect("a request");
    let waiting = tokio::spawn(submit(State(state.clone()), req));
    let answer = answer_on_stop(stop, waiting).await;
    let resp = answer.into_response();
    assert_eq!(resp.status(), StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(resp.headers()["retry-after"], "5");
    drop(held);
}

/// A textured submission waits for room to decode its textures (counted from their headers
/// before decoding, at most `--max-scene-texture-pixels` at a time across submissions),
/// and is answered `503` when the service stops. (Small PNGs of large images, decoded all
/// at once, would hold gigabytes.)
#[tokio::test]
async fn a_submission_waiting_to_decode_its_textures_answers_when_the_service_stops() {
    let (stop, stopping) = watch::channel(false);
    let state = state(stopping).await;
    let mut held = state.receiving.hold();
    held.grow_texels(u64::MAX, Duration::from_secs(1))
        .await
        .expect("every texel");
    let req = textured(
        "[OBJECT]\ntype = sphere\ntexture = t0.png\n[/OBJECT]\n",
        &[(4, 4)],
    );
    let waiting = tokio::spawn(submit(State(state.clone()), req));
    let resp = answer_on_stop(stop, waiting).await.into_response();
    assert_eq!(resp.status(), StatusCode::SERVICE_UNAVAILABLE);
    drop(held);
}

/// Textures past a job's own limit (`--max-scene-texture-pixels`) are refused at once with
/// the check's `400`, without waiting for room to decode them (they would wait, ahead of
/// every other submission, for every texel there is, to be refused after all).
#[tokio::test]
async fn textures_past_the_jobs_limit_are_refused_without_waiting() {
    let (_stop, stopping) = watch::channel(false);
    let mut cfg = Config::defaults();
    cfg.max_scene_texture_pixels = 20;
    let state = state_with(cfg, stopping).await;
    let mut held = state.receiving.hold();
    held.grow_texels(u64::MAX, Duration::from_secs(1))
        .await
        .expect("every texel");
    let req = textured(
        "[OBJECT]\ntype = sphere\ntexture = t0.png\n[/OBJECT]\n\
         [OBJECT]\ntype = sphere\ntexture = t1.png\n[/OBJECT]\n",
        &[(4, 4), (4, 4)],
    );
    let answer = tokio::time::timeout(Duration::from_secs(5), submit(State(state.clone()), req))
        .await
        .expect("answered without waiting for room");
    let resp = answer.into_response();
    assert_eq!(resp.status(), StatusCode::BAD_REQUEST);
    drop(held);
}

/// A submission that needs no more room than there is goes on while the service stops:
/// only one that must wait is answered `503` (a random pick between the two would cut half the
/// uploads under way).
#[tokio::test]
async fn a_submission_with_room_is_served_while_the_service_stops() {
    let (stop, stopping) = watch::channel(false);
    let state = state(stopping).await;
    stop.send(true).expect("a receiver");
    for i in 0..20 {
        let scene = "[GLOBALS]\nwidth = 8\nheight = 8\n[/GLOBALS]\n";
        let req = axum::http::Request::post("/jobs")
            .header("content-length", scene.len())
            .body(axum::body::Body::from(scene))
            .expect("a request");
        let resp = submit(State(state.clone()), req).await.into_response();
        assert_eq!(resp.status(), StatusCode::CREATED, "submission {i}");
    }
}
