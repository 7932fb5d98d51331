//! A worker's servers: one service, or several replicas of one farm (`--server
//! URL1,URL2,...`), and the requests that move from one to another when one stops
//! answering ([`Servers`]).
//!
//! Claims go to the server a slot asks for, or the next in turn that answers. Every request
//! about a claimed tile (its scene and textures, renewals, its result, a failure, a
//! give-back) goes first to the server that handed the tile out ([`Claimed::from`]) and,
//! when that one does not answer, to another: a lease is the farm's database's, not one
//! replica's, so any replica takes it. The servers' health (which answer, and when one that
//! failed is asked again) is `health.rs`'s, kept in memory only; this module sends the
//! requests, reports what came of them, and logs each server's going away and coming back.
//!
//! Not the HTTP of each route (`client.rs`), nor when a slot claims or retries.

use std::future::Future;
use std::ops::Deref;
use std::pin::Pin;
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use bytes::Bytes;
use tessera_protocol::{Claim, ClaimRequest, JobSpec};
use tokio::sync::watch;
use tracing::{info, warn};

use crate::backoff::seed;
use crate::client::{Client, ClientError, Posted, Said, http_client, service_urls};
use crate::health::{Change, Failure, Health};

type Result<T> = std::result::Result<T, ClientError>;

/// One request to one server, boxed so that a request can be sent to one server after
/// another.
type Call<'a, T> = Pin<Box<dyn Future<Output = Result<T>> + Send + 'a>>;

/// A claim and the server that handed it out, which its later requests go to first.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Claimed {
    pub(crate) claim: Claim,
    /// The index of the server in the worker's list.
    pub(crate) from: usize,
}

impl Deref for Claimed {
    type Target = Claim;

    fn deref(&self) -> &Claim {
        &self.claim
    }
}

/// The longest back-off of a worker's only server: a restarted service is asked again
/// within some seconds.
const ONE_SERVER_BACKOFF: Duration = Duration::from_secs(2);

/// The longest back-off of one of several servers: the others carry the work meanwhile, and
/// a replica that is down gets one request per ten seconds or so from each worker.
const REPLICA_BACKOFF: Duration = Duration::from_secs(10);

/// The servers of one worker, and their health, shared by its slots.
#[derive(Debug)]
pub(crate) struct Servers {
    clients: Vec<Client>,
    health: Mutex<Health>,
    /// Bumped whenever a server comes back, waking claims that wait for one.
    back: watch::Sender<u64>,
}

/// How a failed request bears on its server's health; `None` for an answer (a refusal is
/// one: the server is there).
fn failure(e: &ClientError) -> Option<Failure> {
    match e {
        ClientError::Unreachable(_) => Some(Failure::Away),
        ClientError::Status {
            status: 503 | 429,
            retry_after: Some(asked),
            ..
        } => Some(Failure::Busy(*asked)),
        ClientError::Status { status: 429, .. } => Some(Failure::Busy(Duration::ZERO)),
        ClientError::Status { status, .. } if *status >= 500 => Some(Failure::Away),
        _ => None,
    }
}

impl Servers {
    /// The servers of `list` (see [`service_urls`]), each sent `token` when given. A server
    /// that fails backs off up to `idle_max` or, whichever is longer, some seconds (2 for
    /// one server, 10 for one of several).
    pub(crate) fn new(list: &str, token: Option<String>, idle_max: Duration) -> Result<Servers> {
        let urls = service_urls(list)?;
        let http = http_client()?;
        let clients: Vec<Client> = urls
            .into_iter()
            .map(|url| Client::new(http.clone(), url, token.clone()))
            .collect();
        let cap = if clients.len() > 1 {
            REPLICA_BACKOFF
        } else {
            ONE_SERVER_BACKOFF
        };
        Ok(Servers {
            health: Mutex::new(Health::new(clients.len(), idle_max.max(cap), seed())),
            clients,
            back: watch::Sender::new(0),
        })
    }

    /// How many servers there are (at least one).
    pub(crate) fn len(&self) -> usize {
        self.clients.len()
    }

    fn health(&self) -> MutexGuard<'_, Health> {
        // Held only for a few arithmetic steps, never across an await; a poisoned lock's
        // state is still sound (every step leaves it consistent).
        self.health.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Sends `call` to server `i` and notes what came of it in the servers' health.
    async fn ask<T>(&self, i: usize, call: Call<'_, T>) -> Result<T> {
        let sent = Instant::now();
        let answer = call.await;
        let now = Instant::now();
        let change = {
            let mut health = self.health();
            match answer.as_ref().err().and_then(failure) {
                Some(f) => health.failed(i, f, sent, now),
                None => health.answered(i, sent, now),
            }
        };
        if let Some(change) = change {
            self.report(i, change, answer.as_ref().err());
        }
        answer
    }

    /// Logs a server's going away or coming back (once each: `Health` reports a change
    /// once).
    fn report(&self, i: usize, change: Change, error: Option<&ClientError>) {
        let server = self.clients[i].base().as_str();
        let several = self.len() > 1;
        match change {
            Change::Away => {
                let why = error.map_or_else(|| "no answer".to_string(), ToString::to_string);
                if several {
                    warn!(server, "{why}; using the other servers meanwhile");
                } else {
                    warn!(server, "{why}; retrying with back-off");
                }
            }
            Change::Back(after) => {
                info!(
                    server,
                    "the service answers again after {:.1} s",
                    after.as_secs_f64()
                );
                self.back.send_modify(|n| *n = n.wrapping_add(1));
            }
        }
    }

    /// Sends a request about a claimed tile: to `first` (the server that handed the tile
    /// out), then to the others in turn while a server does not answer (or asks to be left
    /// alone), skipping those that are backing off. When every server is backing off, it
    /// goes to `first` all the same: one request, which the caller retries, if at all, with
    /// its own back-off. Answers the first answer and the server that gave it, or the last
    /// error; a refusal that retrying cannot fix is answered at once.
    async fn each<'a, T>(
        &'a self,
        first: usize,
        call: impl Fn(&'a Client) -> Call<'a, T>,
    ) -> Result<(usize, T)> {
        let n = self.len();
        let mut last = None;
        for i in (0..n).map(|k| (first + k) % n) {
            if !self.health().take(i, Instant::now()) {
                continue;
            }
            match self.ask(i, call(&self.clients[i])).await {
                Ok(v) => return Ok((i, v)),
                Err(e) if e.is_transient() => last = Some(e),
                Err(e) => return Err(e),
            }
        }
        match last {
            Some(e) => Err(e),
            None => self
                .ask(first, call(&self.clients[first]))
                .await
                .map(|v| (first, v)),
        }
    }

    /// Claims the next tile as `worker`, from server `first` or else the next in turn that
    /// answers (each waits up to `wait` at the service for work); `None` when that server
    /// has no work, or once `stop` says the worker is stopping. While no server may be
    /// asked (all are backing off) it waits for the first to be due, or to come back, so
    /// it never answers an error that waiting may mend: only a refusal that retrying
    /// cannot fix.
    pub(crate) async fn claim(
        &self,
        first: usize,
        req: &ClaimRequest,
        wait: Duration,
        mut stop: watch::Receiver<bool>,
    ) -> Result<Option<Claimed>> {
        let n = self.len();
        let mut first = first % n;
        loop {
            if *stop.borrow() {
                return Ok(None);
            }
            // Subscribed before the health is read, so that a server coming back between
            // the two still wakes the wait below.
            let mut back = self.back.subscribe();
            let now = Instant::now();
            let (pick, due) = {
                let mut health = self.health();
                (health.pick(first, now), health.next_due(now))
            };
            let Some(i) = pick else {
                let until = due.unwrap_or(now + ONE_SERVER_BACKOFF);
                tokio::select! {
                    () = tokio::time::sleep_until(until.into()) => {}
                    _ = back.changed() => {}
                    _ = stop.changed() => {}
                }
                continue;
            };
            match self
                .ask(i, Box::pin(self.clients[i].claim(req, wait)))
                .await
            {
                Ok(c) => return Ok(c.map(|claim| Claimed { claim, from: i })),
                // Marked in the health: the next try goes to the next server, or waits.
                Err(e) if e.is_transient() => first = (i + 1) % n,
                Err(e) => return Err(e),
            }
        }
    }

    /// The job's scene and sampler settings, from `from` first.
    pub(crate) async fn job(&self, from: usize, job: &str) -> Result<JobSpec> {
        self.each(from, |c| Box::pin(c.job(job)))
            .await
            .map(|(_, spec)| spec)
    }

    /// One of the job's assets, from `from` first.
    pub(crate) async fn asset(&self, from: usize, job: &str, name: &str) -> Result<Vec<u8>> {
        self.each(from, |c| Box::pin(c.asset(job, name)))
            .await
            .map(|(_, bytes)| bytes)
    }

    /// Extends the tile's lease (see [`Client::renew`]).
    pub(crate) async fn renew(&self, c: &Claimed, rendering: bool) -> Result<bool> {
        self.each(c.from, |s| Box::pin(s.renew(&c.claim, rendering)))
            .await
            .map(|(_, held)| held)
    }

    /// Posts a tile blob (see [`Client::post_tile`]); the next claim it brings back is the
    /// answering server's.
    pub(crate) async fn post_tile(
        &self,
        c: &Claimed,
        blob: Bytes,
        next: Option<&str>,
        said: &Said,
    ) -> Result<(Posted, Option<Claimed>)> {
        let (from, posted) = self
            .each(c.from, |s| {
                Box::pin(s.post_tile(&c.claim, blob.clone(), next, said))
            })
            .await?;
        let claimed = match &posted {
            Posted::Accepted { next, .. } => next.clone().map(|claim| Claimed { claim, from }),
            Posted::Stale(_) => None,
        };
        Ok((posted, claimed))
    }

    /// Reports that this worker could not render the tile.
    pub(crate) async fn fail(&self, c: &Claimed, worker: &str, reason: &str) -> Result<()> {
        self.each(c.from, |s| Box::pin(s.fail(&c.claim, worker, reason)))
            .await
            .map(|_| ())
    }

    /// Says that the worker stops cleanly, to the first server that answers (they share
    /// one database, so one is enough).
    pub(crate) async fn bye(&self, worker: &str) -> Result<()> {
        let mut last = None;
        for c in &self.clients {
            match c.bye(worker).await {
                Ok(()) => return Ok(()),
                Err(e) => last = Some(e),
            }
        }
        last.map_or(Ok(()), Err)
    }

    /// Gives the tile back unrendered (see [`Client::release`]).
    pub(crate) async fn release(&self, c: &Claimed) -> Result<bool> {
        self.each(c.from, |s| Box::pin(s.release(&c.claim)))
            .await
            .map(|(_, taken)| taken)
    }
}
