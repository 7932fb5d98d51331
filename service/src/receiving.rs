//! How much memory submissions hold while they are received and checked: one budget shared
//! by every `POST /jobs`.
//!
//! A submission is read whole, then parsed and checked (its textures decoded) before anything
//! is stored. `--max-body-bytes` bounds one body; this budget bounds how many are held at
//! once, and what their textures decode to (a small PNG of one colour can decode to many
//! megabytes of texels). Each submission holds a share of the budget ([`Held`]) that grows
//! with what it holds:
//!
//! - its body: its declared length (the body limit if it declares none) before any of it
//!   is read, all or nothing, so that no share ever waits while it holds part of a body
//!   (shares that held part of one and waited for the rest would shut each other out until
//!   the wait limit); a body that stops arriving for [`BODY_SILENCE`] is cut (`408`) and its
//!   share given back, so that a client that declares a large body and falls silent cannot
//!   shut every submission out until the idle timeout;
//! - its scene's check: parsing and checking a scene takes memory in proportion to its
//!   text, up to [`CHECK_BYTES_PER_SCENE_BYTE`] times it (a scene of the smallest objects),
//!   charged before parsing against a budget of its own (`--max-checking-bytes`), so that
//!   many large scenes arriving at once are checked in turn rather than all at once;
//! - its textures' texels, counted from their headers before they are decoded, against a
//!   budget of their own: at most one job's worth (`--max-scene-texture-pixels`) is
//!   decoded at a time. (In the same budget as bodies, shares holding their bodies while
//!   they waited for texels would shut each other out.) A share takes its check's room
//!   before its texels' and never the other way round, so that no two wait for each other.
//!
//! A share that cannot grow waits its turn (first come, first served), at most
//! [`Receiving::wait_limit`]; the submission is then answered `503` with `Retry-After` and
//! its share given back. Everything is given back when the submission is answered.
//!
//! **What it is not.** It does not limit connections, nor other routes' bodies (a tile's is
//! bounded by its size), nor what a job costs once stored. The pace of a body is `upload`'s
//! to judge (a body below `--min-upload-rate` or past `--max-upload-secs` is cut there, and
//! its share given back with it). A client that gives up while waiting for room is noticed only when its wait ends (nothing
//! reads its connection meanwhile), so it can hold its place in line until then.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// How long a body being received may fall silent before it is cut (`408`) and its share
/// given back (at most a second under the idle timeout, which would close it unanswered).
pub const BODY_SILENCE: Duration = Duration::from_secs(10);

/// The budget is counted in whole KiB: tokio's semaphore counts permits in `u32` per request.
const UNIT: u64 = 1024;

/// What checking a scene may take, per byte of its text: the most measured, a scene of
/// the smallest objects (`[OBJECT]`, `type=cube`, `[/OBJECT]`: 27 bytes each, about 700 bytes
/// of block tree and scene description while parsed), with room to spare.
pub const CHECK_BYTES_PER_SCENE_BYTE: u64 = 32;

/// The submission budget (see the module comment).
#[derive(Debug, Clone)]
pub struct Receiving {
    permits: Arc<Semaphore>,
    units: usize,
    /// Texels being decoded, in units of 1,024.
    texels: Arc<Semaphore>,
    texel_units: usize,
    /// Memory for checking scenes, in KiB.
    checking: Arc<Semaphore>,
    checking_units: usize,
}

/// One submission's share of the budget; given back when dropped.
#[derive(Debug)]
pub struct Held {
    budget: Receiving,
    /// Bytes the share covers (rounded up to whole units in `room`).
    bytes: u64,
    room: Option<OwnedSemaphorePermit>,
    /// Texels being decoded (see [`Held::grow_texels`]).
    texels: Option<OwnedSemaphorePermit>,
    /// Memory for checking the scene (see [`Held::grow_checking`]).
    checking: Option<OwnedSemaphorePermit>,
    /// Whether a `grow` found no room in time: the submission's answer is `503`.
    refused: bool,
    /// Whether the body fell silent past [`BODY_SILENCE`]: the answer is `408`.
    stalled: bool,
    /// Why the body was cut for arriving too slowly or for too long: the answer is `408`.
    too_slow: Option<String>,
}

/// The budget stayed full for as long as a submission may wait.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the service is receiving and checking as much as it takes at once")]
pub struct Full;

impl Receiving {
    /// A budget of `bytes` of bodies (rounded up to whole KiB, at least one), `texels` of
    /// textures being decoded (rounded up to units of 1,024) and `checking` bytes of memory
    /// for checking scenes (rounded up to whole KiB).
    pub fn new(bytes: usize, texels: u64, checking: u64) -> Receiving {
        let units = |n: u64| n.div_ceil(UNIT).clamp(1, Semaphore::MAX_PERMITS as u64) as usize;
        let (body_units, texel_units) = (units(bytes as u64), units(texels));
        let checking_units = units(checking);
        Receiving {
            permits: Arc::new(Semaphore::new(body_units)),
            units: body_units,
            texels: Arc::new(Semaphore::new(texel_units)),
            texel_units,
            checking: Arc::new(Semaphore::new(checking_units)),
            checking_units,
        }
    }

    /// What checking a scene of `scene_bytes` bytes is charged.
    pub fn check_cost(scene_bytes: usize) -> u64 {
        (scene_bytes as u64).saturating_mul(CHECK_BYTES_PER_SCENE_BYTE)
    }

    /// The longest a submission waits for room at a time: at most 30 s, and no longer than
    /// its connection may stay silent (`silence`, [`crate::Config::longest_silence`]):
    /// nothing is read from it meanwhile, and the idle timeout would close it unanswered.
    pub fn wait_limit(silence: Duration) -> Duration {
        silence.min(Duration::from_secs(30))
    }

    /// An empty share, for one submission.
    pub fn hold(&self) -> Held {
        Held {
            budget: self.clone(),
            bytes: 0,
            room: None,
            texels: None,
            checking: None,
            refused: false,
            stalled: false,
            too_slow: None,
        }
    }

    /// Room left, in bytes (rounded to units): for tests and logs.
    pub fn available(&self) -> u64 {
        self.permits.available_permits() as u64 * UNIT
    }
}

impl Held {
    /// Grows the share by `more` bytes, waiting up to `within` for the room. The share never
    /// asks for more than the whole budget: a submission larger than the budget waits for
    /// all of it rather than for ever. On [`Full`] the share keeps what it had (the caller
    /// answers and drops it) and remembers the refusal ([`Held::refused`]).
    pub async fn grow(&mut self, more: u64, within: Duration) -> Result<(), Full> {
        let held_units = self.units();
        let bytes = self.bytes.saturating_add(more);
        let target = bytes.div_ceil(UNIT).min(self.budget.units as u64);
        let need = u32::try_from(target.saturating_sub(held_units)).unwrap_or(u32::MAX);
        if need > 0 {
            let acquire = self.budget.permits.clone().acquire_many_owned(need);
            match tokio::time::timeout(within, acquire).await {
                Ok(Ok(room)) => match &mut self.room {
                    Some(held) => held.merge(room),
                    None => self.room = Some(room),
                },
                // The semaphore is never closed; a closed one admits no one.
                Ok(Err(_)) | Err(_) => {
                    self.refused = true;
                    return Err(Full);
                }
            }
        }
        self.bytes = bytes;
        Ok(())
    }

    /// Takes room for `texels` texels of textures to decode (at most the whole texel budget),
    /// waiting up to `within`; once only, before the textures are decoded.
    pub async fn grow_texels(&mut self, texels: u64, within: Duration) -> Result<(), Full> {
        let budget = (self.budget.texels.clone(), self.budget.texel_units);
        self.texels = self.take_once(budget, texels, within).await?;
        Ok(())
    }

    /// Gives back the room taken for texels (the textures are decoded and dropped).
    pub fn release_texels(&mut self) {
        self.texels = None;
    }

    /// Takes room for checking a scene whose check may take `bytes` (at most the whole
    /// budget), waiting up to `within`; once only, before the scene is parsed.
    pub async fn grow_checking(&mut self, bytes: u64, within: Duration) -> Result<(), Full> {
        let budget = (self.budget.checking.clone(), self.budget.checking_units);
        self.checking = self.take_once(budget, bytes, within).await?;
        Ok(())
    }

    /// Room for `amount` (in units of 1,024, at most the whole of `budget`: its semaphore and
    /// its size) taken at once, waiting up to `within`; `None` when nothing is asked. On
    /// [`Full`] the share remembers the refusal ([`Held::refused`]).
    async fn take_once(
        &mut self,
        (budget, units): (Arc<Semaphore>, usize),
        amount: u64,
        within: Duration,
    ) -> Result<Option<OwnedSemaphorePermit>, Full> {
        let need = amount.div_ceil(UNIT).min(units as u64);
        let need = u32::try_from(need).unwrap_or(u32::MAX);
        if need == 0 {
            return Ok(None);
        }
        match tokio::time::timeout(within, budget.acquire_many_owned(need)).await {
            Ok(Ok(room)) => Ok(Some(room)),
            // The semaphore is never closed; a closed one admits no one.
            Ok(Err(_)) | Err(_) => {
                self.refused = true;
                Err(Full)
            }
        }
    }

    /// Gives back the room taken for checking the scene (it is checked and dropped).
    pub fn release_checking(&mut self) {
        self.checking = None;
    }

    /// Marks the body cut for its silence.
    pub fn stall(&mut self) {
        self.stalled = true;
    }

    /// Marks the body cut for its pace (`why`, said to the client).
    pub fn cut_slow(&mut self, why: String) {
        self.too_slow = Some(why);
    }

    /// Why the body was cut for its pace, if it was.
    pub fn too_slow(&self) -> Option<&str> {
        self.too_slow.as_deref()
    }

    /// Whether the body was cut for its silence.
    pub fn stalled(&self) -> bool {
        self.stalled
    }

    /// Marks the share refused: its submission is answered `503` (the service is stopping).
    pub fn refuse(&mut self) {
        self.refused = true;
    }

    /// Whether a `grow` ran out of time, or the share was refused.
    pub fn refused(&self) -> bool {
        self.refused
    }

    /// The bytes the share covers.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    fn units(&self) -> u64 {
        self.room.as_ref().map_or(0, |r| r.num_permits() as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LONG: Duration = Duration::from_secs(600);
    const NOW: Duration = Duration::from_millis(1);

    /// Shares grow a little at a time, wait when the budget is full, get their room when
    /// another share is dropped, and are counted in bytes, not in calls (a body arriving a
    /// byte at a time holds what it sent, not a unit per byte).
    #[tokio::test]
    async fn shares_grow_by_the_byte_and_wait_for_room() {
        let budget = Receiving::new(1000 * UNIT as usize, UNIT, UNIT);
        let mut first = budget.hold();
        for _ in 0..600 * UNIT {
            first.grow(1, LONG).await.expect("room");
        }
        assert_eq!(budget.available(), 400 * UNIT);
        let mut second = budget.hold();
        assert_eq!(second.grow(600 * UNIT, NOW).await, Err(Full));
        assert!(second.refused());
        let mut third = budget.hold();
        third.grow(400 * UNIT - 7, LONG).await.expect("fits beside");
        assert_eq!(budget.available(), 0);
        let waiting = tokio::spawn({
            let mut share = budget.hold();
            async move { share.grow(600 * UNIT, LONG).await.map(|()| share) }
        });
        // A current-thread runtime: the task runs only when this one yields.
        for _ in 0..10 {
            tokio::task::yield_now().await;
        }
        assert!(!waiting.is_finished(), "no room until the first is dropped");
        drop(first);
        let got = waiting
            .await
            .expect("task")
            .expect("room once the first ended");
        assert_eq!(got.bytes(), 600 * UNIT);
        drop((got, third, second));
        assert_eq!(budget.available(), 1000 * UNIT, "all room given back");
    }

    /// Texels come from a budget of their own: shares that hold their bodies while they
    /// wait for texels leave the body budget to others, and a share that asks for more
    /// texels than there are takes them all once they are free.
    #[tokio::test]
    async fn texels_have_a_budget_of_their_own() {
        let budget = Receiving::new(100 * UNIT as usize, 64 * UNIT, UNIT);
        let mut a = budget.hold();
        a.grow(60 * UNIT, LONG).await.expect("body");
        a.grow_texels(u64::MAX, LONG).await.expect("all the texels");
        let mut b = budget.hold();
        b.grow(40 * UNIT, LONG).await.expect("body beside a's");
        assert_eq!(b.grow_texels(1, NOW).await, Err(Full));
        drop(a);
        b.grow_texels(64 * UNIT, LONG)
            .await
            .expect("texels once a is done");
        assert_eq!(budget.available(), 60 * UNIT);
    }

    /// A share that asks for more than the whole budget takes all of it once it is free,
    /// instead of waiting for more room than there is.
    #[tokio::test]
    async fn a_share_past_the_budget_takes_all_of_it() {
        let budget = Receiving::new(10 * UNIT as usize, UNIT, UNIT);
        let mut big = budget.hold();
        big.grow(u64::MAX / 2, LONG).await.expect("room");
        big.grow(u64::MAX / 2, LONG).await.expect("no more to ask");
        assert_eq!(budget.available(), 0);
        assert_eq!(budget.hold().grow(1, NOW).await, Err(Full));
        drop(big);
        budget.hold().grow(1, LONG).await.expect("room again");
    }

    /// Checks have a budget of their own, taken before texels: a share waits for its check's
    /// room while another checks, and a share past the budget takes all of it.
    #[tokio::test]
    async fn checks_have_a_budget_of_their_own() {
        let budget = Receiving::new(100 * UNIT as usize, 64 * UNIT, 100 * UNIT);
        let mut a = budget.hold();
        a.grow_checking(Receiving::check_cost(2 * UNIT as usize), LONG)
            .await
            .expect("room for a's check");
        let mut b = budget.hold();
        b.grow(10 * UNIT, LONG)
            .await
            .expect("b's body beside a's check");
        assert_eq!(
            b.grow_checking(Receiving::check_cost(2 * UNIT as usize), NOW)
                .await,
            Err(Full),
            "64 KiB of 100 are a's"
        );
        a.release_checking();
        b.grow_checking(u64::MAX, LONG)
            .await
            .expect("the whole budget once a's check is done");
        assert_eq!(
            budget.hold().grow_checking(1, NOW).await,
            Err(Full),
            "b holds it all"
        );
        drop(b);
        budget
            .hold()
            .grow_checking(1, LONG)
            .await
            .expect("room again");
    }
}
