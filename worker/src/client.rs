//! The worker's HTTP client for the service's worker routes: one method per route, typed
//! answers, and errors that say whether trying again later can help.
//!
//! It does not decide when to retry or back off; that is the worker loop's business.

use std::time::Duration;

use bytes::Bytes;
use reqwest::{StatusCode, Url};
use tessera_protocol::{Accepted, Bye, Claim, ClaimRequest, FailRequest, JobSpec, Renewed};

/// Why a request to the service did not give a usable answer.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The service URL cannot be used (see `--server`).
    #[error("bad service URL `{url}`: {why}")]
    BadUrl {
        /// The URL as given, without its password.
        url: String,
        /// What is wrong with it.
        why: &'static str,
    },
    /// The request did not get an answer: the service is down, the name does not resolve,
    /// or the connection failed.
    ///
    /// Shown with its causes: reqwest's own message is "error sending request for url"
    /// whether the connection is refused, the name does not resolve or TLS fails.
    #[error("cannot reach the service: {}", with_causes(.0))]
    Unreachable(#[source] reqwest::Error),
    /// The service refused the worker's token.
    #[error("the service refused this worker's token (401); check --token")]
    Unauthorized,
    /// The service requires a token, and the worker has none.
    #[error(
        "the service requires a worker token (401); give it with --token or \
         TESSERA_WORKER_TOKEN"
    )]
    NoToken,
    /// The service answered with a status the route does not expect.
    #[error("{what}: the service answered {status}: {body}")]
    Status {
        /// The request, in words.
        what: &'static str,
        /// The answer's HTTP status code.
        status: u16,
        /// The answer's body, as text.
        body: String,
        /// The answer's `Retry-After`, in seconds (at most [`MAX_RETRY_AFTER`]).
        retry_after: Option<Duration>,
    },
    /// The answer's body is not what the route answers.
    #[error("{what}: unreadable answer: {source}")]
    Decode {
        /// The request, in words.
        what: &'static str,
        /// Why it could not be read.
        #[source]
        source: reqwest::Error,
    },
}

/// An error's message followed by those of its sources, `: `-separated, each once (a
/// source's message often repeats its cause's).
fn with_causes(e: &(dyn std::error::Error + 'static)) -> String {
    let mut out = e.to_string();
    let mut next = e.source();
    while let Some(cause) = next {
        let text = cause.to_string();
        if !out.contains(&text) {
            out.push_str(": ");
            out.push_str(&text);
        }
        next = cause.source();
    }
    out
}

/// The longest `Retry-After` a worker honours: a service that asks for more is asked
/// again after this.
pub const MAX_RETRY_AFTER: Duration = Duration::from_secs(60);

impl ClientError {
    /// How long the service asked to be left alone (`Retry-After` on its answer), if it did:
    /// a service pausing its work for a full disk says 5 s.
    pub fn retry_after(&self) -> Option<Duration> {
        match self {
            ClientError::Status { retry_after, .. } => *retry_after,
            _ => None,
        }
    }

    /// Whether waiting and trying again may help (the service is down or busy), as opposed
    /// to a refusal that will not change.
    pub fn is_transient(&self) -> bool {
        match self {
            ClientError::Unreachable(_) => true,
            ClientError::Status { status, .. } => *status >= 500 || *status == 429,
            _ => false,
        }
    }
}

/// The service's base URL, checked: `http://` with a host (and a path, for a service behind
/// a proxy that adds one). This build has no TLS, so `https://` is refused here, at start,
/// rather than failing every request for ever. A user name or password is also refused: it
/// would go to the service in clear on every request and show in the worker's log (the
/// token is `--token`'s); so are a query and a fragment, which every request's own would
/// have been appended to, and white space around the URL, which the parser would
/// drop silently. A password is not repeated in the message.
pub(crate) fn service_url(server: &str) -> Result<Url> {
    const EXPECTED: &str = "expected http://HOST:PORT (this worker speaks plain HTTP, not TLS: \
                            reach a service behind https through a local tunnel or proxy)";
    let shown = without_password(server);
    let bad = |why| ClientError::BadUrl {
        url: shown.clone(),
        why,
    };
    if server.trim() != server {
        return Err(bad("it starts or ends with white space"));
    }
    let url = Url::parse(server).map_err(|_| bad(EXPECTED))?;
    if url.scheme() != "http" || url.cannot_be_a_base() || url.host().is_none() {
        return Err(bad(EXPECTED));
    }
    if !url.username().is_empty() || url.password().is_some() {
        return Err(bad(
            "no user name or password: they would go to the service in clear and show in \
             logs (a token goes in --token)",
        ));
    }
    if url.query().is_some() || url.fragment().is_some() {
        return Err(bad(
            "no ?query or #fragment: the worker's requests carry their own",
        ));
    }
    Ok(url)
}

/// A `--server` list: one URL, or several separated by commas (replicas of one farm), each
/// checked by [`service_url`]. An empty entry and a URL given twice are refused.
pub(crate) fn service_urls(list: &str) -> Result<Vec<Url>> {
    let mut urls: Vec<Url> = Vec::new();
    for item in list.split(',') {
        if item.is_empty() {
            return Err(ClientError::BadUrl {
                url: list
                    .split(',')
                    .map(without_password)
                    .collect::<Vec<_>>()
                    .join(","),
                why: "an empty entry in the list (URLs are separated by single commas)",
            });
        }
        let url = service_url(item)?;
        if urls.contains(&url) {
            return Err(ClientError::BadUrl {
                url: without_password(item),
                why: "given twice in the list",
            });
        }
        urls.push(url);
    }
    Ok(urls)
}

/// `server` as a message may show it: whatever stands between `://` and the last `@`
/// before the host's end (a user name and password) as `***`, whether or not the rest
/// parses.
fn without_password(server: &str) -> String {
    let Some((scheme, rest)) = server.split_once("://") else {
        return server.to_string();
    };
    let authority_end = rest.find(['/', '?', '#']).unwrap_or(rest.len());
    match rest[..authority_end].rfind('@') {
        Some(at) => format!("{scheme}://***{}", &rest[at..]),
        None => server.to_string(),
    }
}

/// `Ok` for an error that waiting may mend (the service is down or busy), which the caller
/// passes over: a tile it could not give back or report on returns when its lease runs out.
/// Other errors are returned.
pub(crate) fn ignore_transient(e: ClientError) -> Result<()> {
    if e.is_transient() { Ok(()) } else { Err(e) }
}

/// What became of a posted tile.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Posted {
    /// Stored (or, `repeat`, already stored from this lease), with the next claim when one
    /// is asked for and there is work.
    Accepted { repeat: bool, next: Option<Claim> },
    /// Refused because the lease is not this worker's any more (it expired and went to another
    /// worker, or the job is cancelled): the tile is someone else's business now.
    Stale(String),
}

/// A client for one service (one of a worker's servers: `servers.rs` holds them all).
#[derive(Debug, Clone)]
pub(crate) struct Client {
    http: reqwest::Client,
    base: Url,
    token: Option<String>,
}

type Result<T> = std::result::Result<T, ClientError>;

/// The longest a goodbye waits for its answer: the worker is stopping, and a service that
/// does not answer at once only learns of it later (the worker shows gone once silent).
const BYE_TIMEOUT: Duration = Duration::from_secs(2);

/// What one tile cost its worker: said with its result, for the service's metrics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct Spent {
    /// The rays it took.
    pub(crate) rays: u64,
    /// The render-thread time it took, in milliseconds, over all its strips.
    pub(crate) render_ms: u64,
}

/// What a posted tile says besides its pixels: its cost, and the worker's threads and
/// rays per second (see [`tessera_protocol::ClaimRequest`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Said {
    pub(crate) spent: Spent,
    pub(crate) threads: u32,
    pub(crate) rays_per_second: Option<f64>,
}

/// How much longer than its `wait_ms` a claim may take before it is given up: a service
/// that answers a claim this late is frozen or overloaded, and a worker with several
/// servers asks another meanwhile.
const CLAIM_MARGIN: Duration = Duration::from_secs(10);

/// The longest a renewal may take: one stuck longer holds up its slot (it waits for the
/// answer before it takes the render's), and a renewal that does not get through is
/// harmless (the next one, or the post, comes soon).
const RENEW_WAIT: Duration = Duration::from_secs(10);

/// The HTTP client every [`Client`] of one worker shares (its connection pool holds each
/// server's connections).
pub(crate) fn http_client() -> Result<reqwest::Client> {
    reqwest::Client::builder()
        .connect_timeout(Duration::from_secs(5))
        .timeout(Duration::from_secs(120))
        // Below the service's idle timeout (120 s by default, to be kept above 60), so
        // that an idle connection is dropped here before the service closes it under a
        // request about to be sent.
        .pool_idle_timeout(Duration::from_secs(50))
        .build()
        .map_err(ClientError::Unreachable)
}

impl Client {
    /// A client for the service at `base` (checked by [`service_url`]), sending `token`
    /// with every request when given.
    pub(crate) fn new(http: reqwest::Client, mut base: Url, token: Option<String>) -> Client {
        if !base.path().ends_with('/') {
            let p = format!("{}/", base.path());
            base.set_path(&p);
        }
        Client { http, base, token }
    }

    /// The service's base URL, for logs.
    pub(crate) fn base(&self) -> &Url {
        &self.base
    }

    /// `segments` are appended to the base URL, each percent-encoded as one path segment.
    fn url(&self, segments: &[&str], lease: Option<&str>) -> Url {
        let mut url = self.base.clone();
        {
            // `new` checks that the base is a hierarchical http URL, so it has path
            // segments.
            let mut path = url
                .path_segments_mut()
                .expect("checked in Client::new: base URL can be a base");
            path.pop_if_empty();
            for s in segments {
                path.push(s);
            }
        }
        if let Some(lease) = lease {
            url.query_pairs_mut().append_pair("lease", lease);
        }
        url
    }

    fn auth(&self, req: reqwest::RequestBuilder) -> reqwest::RequestBuilder {
        match &self.token {
            Some(t) => req.bearer_auth(t),
            None => req,
        }
    }

    async fn send(&self, req: reqwest::RequestBuilder) -> Result<reqwest::Response> {
        let resp = self
            .auth(req)
            .send()
            .await
            .map_err(ClientError::Unreachable)?;
        if resp.status() == StatusCode::UNAUTHORIZED {
            return Err(if self.token.is_some() {
                ClientError::Unauthorized
            } else {
                ClientError::NoToken
            });
        }
        Ok(resp)
    }

    async fn fail_status(what: &'static str, resp: reqwest::Response) -> ClientError {
        let status = resp.status().as_u16();
        let retry_after = resp
            .headers()
            .get(reqwest::header::RETRY_AFTER)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.trim().parse::<u64>().ok())
            .map(|secs| Duration::from_secs(secs).min(MAX_RETRY_AFTER));
        let body = resp.text().await.unwrap_or_default();
        ClientError::Status {
            what,
            status,
            body,
            retry_after,
        }
    }

    /// Claims the next tile; `None` when there is no work. With no work at hand the
    /// service waits up to `wait` for some before answering.
    pub(crate) async fn claim(
        &self,
        claim: &ClaimRequest,
        wait: Duration,
    ) -> Result<Option<Claim>> {
        let what = "claim";
        let mut url = self.url(&["worker", "claim"], None);
        url.query_pairs_mut()
            .append_pair("wait_ms", &wait.as_millis().to_string());
        let req = self.http.post(url).timeout(wait + CLAIM_MARGIN).json(claim);
        let resp = self.send(req).await?;
        match resp.status() {
            StatusCode::NO_CONTENT => Ok(None),
            StatusCode::OK => resp
                .json()
                .await
                .map(Some)
                .map_err(|source| ClientError::Decode { what, source }),
            _ => Err(Self::fail_status(what, resp).await),
        }
    }

    /// Says that this worker stops cleanly (`POST /worker/bye`).
    pub(crate) async fn bye(&self, worker: &str) -> Result<()> {
        let what = "goodbye";
        let req = self
            .http
            .post(self.url(&["worker", "bye"], None))
            .timeout(BYE_TIMEOUT)
            .json(&Bye {
                worker: worker.to_string(),
            });
        let resp = self.send(req).await?;
        if resp.status().is_success() {
            Ok(())
        } else {
            Err(Self::fail_status(what, resp).await)
        }
    }

    /// The job's scene and sampler settings.
    pub(crate) async fn job(&self, job: &str) -> Result<JobSpec> {
        let what = "fetch job";
        let resp = self
            .send(self.http.get(self.url(&["worker", "jobs", job], None)))
            .await?;
        if resp.status() != StatusCode::OK {
            return Err(Self::fail_status(what, resp).await);
        }
        resp.json()
            .await
            .map_err(|source| ClientError::Decode { what, source })
    }

    /// One of the job's assets (a texture file).
    pub(crate) async fn asset(&self, job: &str, name: &str) -> Result<Vec<u8>> {
        let what = "fetch asset";
        let url = self.url(&["worker", "jobs", job, "assets", name], None);
        let resp = self.send(self.http.get(url)).await?;
        if resp.status() != StatusCode::OK {
            return Err(Self::fail_status(what, resp).await);
        }
        resp.bytes()
            .await
            .map(|b| b.to_vec())
            .map_err(|source| ClientError::Decode { what, source })
    }

    fn tile_url(&self, c: &Claim, action: Option<&str>) -> Url {
        let idx = c.idx.to_string();
        let mut segs = vec!["worker", "jobs", c.job.as_str(), "tiles", idx.as_str()];
        segs.extend(action);
        self.url(&segs, Some(&c.lease))
    }

    /// Extends the tile's lease; `false` when it is not this worker's any more. `rendering`
    /// says the tile is being rendered rather than held ahead: should the worker stall, the
    /// service charges a failure to the tiles it is rendering only.
    pub(crate) async fn renew(&self, c: &Claim, rendering: bool) -> Result<bool> {
        let what = "renew lease";
        let mut url = self.tile_url(c, Some("renew"));
        if rendering {
            url.query_pairs_mut().append_pair("rendering", "true");
        }
        let resp = self.send(self.http.post(url).timeout(RENEW_WAIT)).await?;
        match resp.status() {
            StatusCode::OK => {
                let _: Renewed = resp
                    .json()
                    .await
                    .map_err(|source| ClientError::Decode { what, source })?;
                Ok(true)
            }
            StatusCode::CONFLICT | StatusCode::NOT_FOUND => Ok(false),
            _ => Err(Self::fail_status(what, resp).await),
        }
    }

    /// Posts a tile blob (see [`tessera_protocol::encode_tile`]). With `next` (this worker's
    /// name), the answer also carries the worker's next tile when there is one at once.
    pub(crate) async fn post_tile(
        &self,
        c: &Claim,
        blob: Bytes,
        next: Option<&str>,
        said: &Said,
    ) -> Result<Posted> {
        let what = "post tile";
        let mut url = self.tile_url(c, None);
        {
            let mut q = url.query_pairs_mut();
            if let Some(name) = next {
                q.append_pair("next", name);
            }
            q.append_pair("rays", &said.spent.rays.to_string())
                .append_pair("render_ms", &said.spent.render_ms.to_string())
                .append_pair("threads", &said.threads.to_string());
            if let Some(rate) = said.rays_per_second {
                q.append_pair("rays_per_second", &format!("{rate:.0}"));
            }
        }
        let req = self
            .http
            .put(url)
            .header(reqwest::header::CONTENT_TYPE, "application/octet-stream")
            .body(blob);
        let resp = self.send(req).await?;
        match resp.status() {
            StatusCode::OK => {
                let a: Accepted = resp
                    .json()
                    .await
                    .map_err(|source| ClientError::Decode { what, source })?;
                Ok(Posted::Accepted {
                    repeat: a.repeat,
                    next: a.next,
                })
            }
            StatusCode::CONFLICT | StatusCode::NOT_FOUND => {
                Ok(Posted::Stale(resp.text().await.unwrap_or_default()))
            }
            _ => Err(Self::fail_status(what, resp).await),
        }
    }

    /// Reports that this worker could not render the tile.
    pub(crate) async fn fail(&self, c: &Claim, worker: &str, reason: &str) -> Result<()> {
        let what = "report failure";
        let req = self
            .http
            .post(self.tile_url(c, Some("fail")))
            .json(&FailRequest {
                worker: worker.to_string(),
                reason: reason.to_string(),
            });
        let resp = self.send(req).await?;
        match resp.status() {
            StatusCode::OK | StatusCode::CONFLICT | StatusCode::NOT_FOUND => Ok(()),
            _ => Err(Self::fail_status(what, resp).await),
        }
    }

    /// Gives the tile back unrendered, without counting it as a failure (shutdown).
    /// `Ok(false)`: the lease is not this worker's any more, so there is nothing to give.
    pub(crate) async fn release(&self, c: &Claim) -> Result<bool> {
        let what = "release tile";
        let resp = self
            .send(self.http.post(self.tile_url(c, Some("release"))))
            .await?;
        match resp.status() {
            StatusCode::OK => Ok(true),
            StatusCode::CONFLICT | StatusCode::NOT_FOUND => Ok(false),
            _ => Err(Self::fail_status(what, resp).await),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refusal(list: &str) -> String {
        match service_urls(list) {
            Err(e) => e.to_string(),
            Ok(urls) => panic!("{list:?} accepted as {urls:?}"),
        }
    }

    #[test]
    fn one_url_or_several_comma_separated() {
        let one = service_urls("http://127.0.0.1:8080").expect("one URL");
        assert_eq!(one.len(), 1);
        assert_eq!(one[0].as_str(), "http://127.0.0.1:8080/");
        let three = service_urls("http://a:1,http://b:2/farm,http://c:3").expect("three replicas");
        let hosts: Vec<_> = three.iter().map(|u| u.host_str().unwrap_or("")).collect();
        assert_eq!(hosts, ["a", "b", "c"]);
        assert_eq!(three[1].path(), "/farm");
    }

    #[test]
    fn a_list_refuses_what_one_url_refuses_and_names_the_entry() {
        assert!(refusal("http://a:1,https://b:2").contains("`https://b:2`"));
        assert!(refusal("http://a:1, http://b:2").contains("white space"));
        assert!(refusal("http://a:1,,http://b:2").contains("empty entry"));
        assert!(refusal("http://a:1,").contains("empty entry"));
        assert!(refusal("http://a:1,http://a:1/").contains("given twice"));
    }

    #[test]
    fn a_refused_list_never_shows_a_password() {
        for list in [
            "http://a:1,,http://u:secret@b:2",
            "http://u:secret@a:1,http://b:2",
            "http://b:2,http://u:secret@a:1",
        ] {
            let e = refusal(list);
            assert!(!e.contains("secret"), "{e}");
        }
    }
}
