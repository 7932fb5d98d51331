//! What a slot has in flight besides the tile it renders: the next claim, the tile queued
//! after the current one, and the posts of earlier tiles ([`Pipeline`]).
//!
//! Bookkeeping and waiting only: the slot loop (`slot.rs`) decides what to start and when.

use std::collections::VecDeque;

use tokio::task::JoinHandle;
use tracing::warn;

use crate::client::ClientError;
use crate::post::PostTask;
use crate::servers::Claimed;
use crate::ticket::Ticket;

/// Posts a slot may have under way at once: the next render never waits for the service
/// unless this many are stuck.
const POSTS_IN_FLIGHT: usize = 4;

/// A claim asked for ahead of time, running as its own task so that it is never dropped
/// half-way (a claim answered but never read would strand its tile until the lease ran out).
pub(crate) type ClaimTask = JoinHandle<Result<Option<Claimed>, ClientError>>;

/// What a slot has in flight besides the tile it renders. While tile N renders, the claim
/// for tile N + 1 is already asked for and, once answered, put in the render thread's
/// queue; tile N − 1's pixels are being posted. The round trips to the service thus overlap
/// with tracing instead of leaving the core idle between tiles. Each slot holds at most one
/// tile ahead, which bounds what a job's last moments can wait for to one tile per slot.
#[derive(Default)]
pub(crate) struct Pipeline {
    /// The next claim, still on its way.
    pub(crate) claim: Option<ClaimTask>,
    /// A claim answer that gave no tile to queue (no work, or an error), for the slot loop.
    pub(crate) next: Option<Result<Option<Claimed>, ClientError>>,
    /// The next tile, in the render thread's queue.
    pub(crate) queued: Option<Ticket>,
    /// Posts of earlier tiles still under way, oldest first (at most [`POSTS_IN_FLIGHT`]).
    posts: VecDeque<PostTask>,
    /// A tile claimed ahead has been given back because its scene or a texture could not be
    /// fetched: the slot backs off before its next claim.
    pub(crate) unfetched: bool,
    /// The server (its index in the worker's list) the slot's next claim goes to first:
    /// each claim goes to the next in turn, so that a slot's claims are spread over its
    /// servers (slots start at different ones).
    pub(crate) turn: usize,
}

impl Pipeline {
    /// The server for the slot's next claim, of `n`; the one after it for the claim after.
    pub(crate) fn next_turn(&mut self, n: usize) -> usize {
        let t = self.turn % n;
        self.turn = (t + 1) % n;
        t
    }

    /// Waits for the claim in flight, if any (forever if none: for `select!`).
    pub(crate) async fn claim_answer(&mut self) -> Result<Option<Claimed>, ClientError> {
        match &mut self.claim {
            Some(task) => task.await.unwrap_or_else(|e| {
                warn!("claim task ended abnormally: {e}");
                Ok(None)
            }),
            None => std::future::pending().await,
        }
    }

    /// Starts posting a rendered tile without waiting for earlier posts, unless
    /// [`POSTS_IN_FLIGHT`] are still under way (the service is slow or unreachable): then
    /// the oldest is waited for first. A refusal that retrying cannot fix is passed on.
    pub(crate) async fn start_post(&mut self, task: PostTask) -> Result<(), ClientError> {
        while self.posts.front().is_some_and(JoinHandle::is_finished)
            || self.posts.len() >= POSTS_IN_FLIGHT
        {
            self.finish_oldest_post().await?;
        }
        self.posts.push_back(task);
        Ok(())
    }

    async fn finish_oldest_post(&mut self) -> Result<(), ClientError> {
        match self.posts.pop_front() {
            Some(task) => task.await.unwrap_or_else(|e| {
                warn!("post task ended abnormally: {e}");
                Ok(())
            }),
            None => Ok(()),
        }
    }

    /// Waits for every post under way; the first refusal is passed on.
    pub(crate) async fn finish_posts(&mut self) -> Result<(), ClientError> {
        let mut first = Ok(());
        while !self.posts.is_empty() {
            let r = self.finish_oldest_post().await;
            if first.is_ok() {
                first = r;
            }
        }
        first
    }
}
