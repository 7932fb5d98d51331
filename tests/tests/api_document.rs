//! The OpenAPI document at `/openapi.json` against the service that serves it: every route
//! the contract names is in it, every route in it is the router's, the error fields it
//! describes are the ones answers carry, and schemathesis, run against it in CI, finds no
//! server error and no answer that strays from it.
//!
//! schemathesis comes from PyPI (`.ci/run` installs it in `target/tools`); without it that
//! test is skipped with a note, unless `TESSERA_CI` is set: then it fails.

mod common;

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{Service, TempDir, client, wait_until};
use serde_json::Value;

/// The user routes of the service's contract, with their methods.
const USER_ROUTES: &[(&str, &str)] = &[
    ("/", "get"),
    ("/jobs", "get"),
    ("/jobs", "post"),
    ("/jobs/{id}", "get"),
    ("/jobs/{id}", "delete"),
    ("/jobs/{id}", "patch"),
    ("/jobs/{id}/retry", "post"),
    ("/jobs/{id}/image.png", "get"),
    ("/jobs/{id}/preview.png", "get"),
    ("/jobs/{id}/events", "get"),
    ("/jobs/{id}/tiles", "get"),
    ("/jobs/{id}/scene", "get"),
    ("/healthz", "get"),
    ("/workers", "get"),
    ("/metrics", "get"),
    ("/openapi.json", "get"),
    ("/api", "get"),
];

const METHODS: [&str; 5] = ["get", "post", "put", "patch", "delete"];

#[test]
fn the_document_is_the_routers_own() {
    let dir = TempDir::new("openapi");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let doc: Value = svc.get_json("/openapi.json");
    assert_eq!(doc["openapi"], "3.1.0");
    let paths = doc["paths"].as_object().expect("paths");
    for (path, method) in USER_ROUTES {
        assert!(
            paths.get(*path).is_some_and(|p| p.get(*method).is_some()),
            "{method} {path} is not in the document"
        );
    }
    // Each route the document lists is routed: asked for with an id that names no job, it
    // is not the router's "no such route" nor "method not allowed".
    for (path, item) in paths {
        for method in METHODS.iter().filter(|m| item.get(**m).is_some()) {
            let url = format!("{}{}", svc.url, path.replace("{id}", "nosuchjob"));
            let req = match *method {
                "get" => client().get(&url),
                "post" => client().post(&url),
                "put" => client().put(&url),
                "patch" => client().patch(&url),
                _ => client().delete(&url),
            };
            let r = req.send().expect("an answer");
            let status = r.status().as_u16();
            let body = r.text().unwrap_or_default();
            assert!(
                status != 405 && !body.contains("no such route"),
                "{method} {path}: {status} {body}"
            );
            // Every answer the document lists has a description.
            for (code, answer) in item[*method]["responses"].as_object().expect("responses") {
                assert!(
                    answer["description"]
                        .as_str()
                        .is_some_and(|d| !d.is_empty()),
                    "{method} {path} {code}"
                );
            }
        }
    }
    // The error fields described are those `ApiError::with` takes.
    let props: Vec<String> = doc["components"]["schemas"]["ErrorBody"]["properties"]
        .as_object()
        .expect("ErrorBody's fields")
        .keys()
        .filter(|k| *k != "error")
        .cloned()
        .collect();
    let mut fields: Vec<String> = tessera_service::ErrorBody::FIELDS
        .iter()
        .map(|f| f.to_string())
        .collect();
    let mut props = props;
    props.sort();
    fields.sort();
    assert_eq!(props, fields);
}

/// The document declares the read token on exactly the reads that `--read-token` guards:
/// asked for without it, every read that declares it is refused, and every other read is
/// answered.
#[test]
fn the_read_token_is_declared_where_reads_need_it() {
    let dir = TempDir::new("openapi-read");
    let svc = Service::start(&dir, &["--local-workers", "0", "--read-token", "r3ad"]);
    let doc: Value = client()
        .get(format!("{}/openapi.json", svc.url))
        .bearer_auth("r3ad")
        .send()
        .expect("an answer")
        .json()
        .expect("the document");
    let scheme = &doc["components"]["securitySchemes"]["read_token"];
    assert_eq!(
        (scheme["type"].as_str(), scheme["scheme"].as_str()),
        (Some("http"), Some("bearer")),
        "{scheme}"
    );
    let paths = doc["paths"].as_object().expect("paths");
    let mut guarded = 0;
    for (path, item) in paths {
        let Some(op) = item.get("get") else { continue };
        let declared = op["security"]
            .as_array()
            .is_some_and(|s| s.iter().any(|r| r.get("read_token").is_some()));
        let r = client()
            .get(format!("{}{}", svc.url, path.replace("{id}", "nosuchjob")))
            .header("Accept", "application/json")
            .send()
            .expect("an answer");
        assert_eq!(r.status() == 401, declared, "GET {path}: {}", r.status());
        guarded += usize::from(declared);
    }
    assert!(guarded >= 8, "{guarded} reads declare the read token");
}

/// schemathesis's command: `TESSERA_SCHEMATHESIS`, the one `.ci/run` installs, or the PATH's.
fn schemathesis() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("TESSERA_SCHEMATHESIS") {
        return Some(p.into());
    }
    let tools = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/tools/bin/schemathesis");
    if tools.exists() {
        return Some(tools);
    }
    Command::new("schemathesis")
        .arg("--version")
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|_| "schemathesis".into())
}

#[test]
fn schemathesis_finds_nothing() {
    let Some(st) = schemathesis() else {
        let why = "schemathesis is not installed (`.ci/run` installs it)";
        assert!(std::env::var_os("TESSERA_CI").is_none(), "{why}");
        eprintln!("skipped: {why}");
        return;
    };
    let dir = TempDir::new("schemathesis");
    // One local worker, so that jobs it submits render and their images exist.
    let svc = Service::start(&dir, &["--local-workers", "1"]);
    let config = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("schemathesis.toml");
    let mut run = Command::new(&st)
        // Its cache of what it found goes into the test's folder, not the source tree.
        .current_dir(dir.path())
        .arg("--config-file")
        .arg(&config)
        .arg("run")
        .arg(format!("{}/openapi.json", svc.url))
        .args(["--checks", "all"])
        // `DELETE /jobs/{id}` cancels a job and keeps it (`?purge=true` removes it): a
        // cancelled job is still there to read, which this check takes for a resource that
        // outlived its deletion.
        .args(["--exclude-checks", "use_after_free"])
        // Bounded for CI: examples per operation, and a fixed seed so that a failure
        // repeats.
        .args(["--max-examples", "60", "--seed", "20261205", "--no-color"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("schemathesis starts");
    let mut status = None;
    wait_until("schemathesis", Duration::from_secs(600), || {
        status = run.try_wait().ok().flatten();
        status.is_some()
    });
    let out = run.wait_with_output().expect("its output");
    assert!(
        status.is_some_and(|s| s.success()),
        "schemathesis found something:\n{}\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
        svc.log()
    );
}
