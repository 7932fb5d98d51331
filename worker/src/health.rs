//! Which of a worker's servers (replicas of one farm) answer, which to ask next, and when
//! one that stopped answering is asked again ([`Health`]).
//!
//! Pure bookkeeping: every method takes the moment it acts at, nothing here sleeps, sends a
//! request or logs. `servers.rs` sends the requests, tells it what came of them, and logs
//! the changes it reports.

use std::time::{Duration, Instant};

use crate::backoff::backoff;

/// What a request to a server told of its health, when it got no usable answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Failure {
    /// No answer (refused, timed out, cut), or a server error (5xx) other than a `503`
    /// with `Retry-After`: the server is taken for gone until it answers again.
    Away,
    /// The server answered that it wants to be left alone for this long (`503` or `429`
    /// with `Retry-After`; zero without one): it is alive, and asked again no sooner.
    Busy(Duration),
}

/// A change in a server's health, for the log: each is reported once, when it happens,
/// not for every request.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Change {
    /// The server stopped answering.
    Away,
    /// The server answers again, after being away this long.
    Back(Duration),
}

/// One server's state.
#[derive(Debug, Clone, Default)]
struct State {
    /// Failures in a row, each lengthening the back-off; 0 while the server answers.
    streak: u32,
    /// The server is not asked before this moment (its back-off, or its `Retry-After`).
    not_before: Option<Instant>,
    /// When the last counted failure came: a failure of a request sent before it tells
    /// nothing new (the requests out at once all fail when a server goes).
    failed_at: Option<Instant>,
    /// Since when the server has not answered; `None` while it answers (or only asked to
    /// be left alone).
    away_since: Option<Instant>,
}

/// The health of a worker's servers, shared by its slots.
///
/// A server that fails is not asked again before its back-off is over: 25 ms doubling with
/// each failure in a row up to `max`, ±50 % jitter, and at least as long as its
/// `Retry-After`. Once the back-off is over, one request probes it ([`Health::take`]
/// reserves the server for it); others wait for that answer, so that a server that is down
/// gets one request per back-off from this worker, however many slots it has.
#[derive(Debug)]
pub(crate) struct Health {
    servers: Vec<State>,
    max: Duration,
    rng: u64,
}

impl Health {
    /// `n` servers, all taken to answer; back-offs up to `max`, jittered from `seed` (odd).
    pub(crate) fn new(n: usize, max: Duration, seed: u64) -> Health {
        Health {
            servers: vec![State::default(); n],
            max,
            rng: seed | 1,
        }
    }

    /// Whether server `i` may be asked at `now` (it answers, or its back-off is over).
    pub(crate) fn usable(&self, i: usize, now: Instant) -> bool {
        self.servers[i].not_before.is_none_or(|t| now >= t)
    }

    /// Takes server `i` for a request sent at `now`, if it may be asked: `false` while its
    /// back-off lasts. A server being probed (asked again after its back-off) is reserved
    /// for the probe for up to `max`, so that no second request goes to it before the first
    /// answers; a probe that never reports (its request dropped) frees it when that is over.
    pub(crate) fn take(&mut self, i: usize, now: Instant) -> bool {
        if !self.usable(i, now) {
            return false;
        }
        let s = &mut self.servers[i];
        if s.not_before.is_some() {
            s.not_before = Some(now + self.max);
        }
        true
    }

    /// The first server from `first` on (in turn, wrapping) that [`Health::take`] takes at
    /// `now`; `None` when every one is backing off.
    pub(crate) fn pick(&mut self, first: usize, now: Instant) -> Option<usize> {
        let n = self.servers.len();
        (0..n).map(|k| (first + k) % n).find(|&i| self.take(i, now))
    }

    /// The moment the first server's back-off is over; `None` if one may be asked now.
    pub(crate) fn next_due(&self, now: Instant) -> Option<Instant> {
        if (0..self.servers.len()).any(|i| self.usable(i, now)) {
            return None;
        }
        self.servers.iter().filter_map(|s| s.not_before).min()
    }

    /// Server `i` answered a request sent at `sent` at `now` (any answer, refusals
    /// included): it is asked freely again. Reports its coming back if it was away. An
    /// answer to a request sent before the last counted failure came tells nothing new
    /// either: a server that dies with several requests out may answer one of them after
    /// another has failed, and that answer must not bring it back.
    pub(crate) fn answered(&mut self, i: usize, sent: Instant, now: Instant) -> Option<Change> {
        let s = &mut self.servers[i];
        if s.failed_at.is_some_and(|last| sent < last) {
            return None;
        }
        s.streak = 0;
        s.not_before = None;
        s.failed_at = None;
        s.away_since
            .take()
            .map(|since| Change::Back(now.saturating_duration_since(since)))
    }

    /// A request to server `i`, sent at `sent`, failed at `now`. It backs off (or, busy,
    /// rests for as long as it asked), unless the request was sent before the last counted
    /// failure came: that one said it all already. Reports the server's going away.
    pub(crate) fn failed(
        &mut self,
        i: usize,
        failure: Failure,
        sent: Instant,
        now: Instant,
    ) -> Option<Change> {
        let s = &mut self.servers[i];
        if s.failed_at.is_some_and(|last| sent < last) {
            return None;
        }
        s.failed_at = Some(now);
        s.streak = s.streak.saturating_add(1);
        let pause = backoff(s.streak, self.max, &mut self.rng);
        let (pause, away) = match failure {
            Failure::Away => (pause, true),
            // Alive: it answered. The back-off still grows, so that a `Retry-After: 0`
            // does not make a tight loop.
            Failure::Busy(asked) => (pause.max(asked), false),
        };
        s.not_before = Some(now + pause);
        if away && s.away_since.is_none() {
            s.away_since = Some(now);
            return Some(Change::Away);
        }
        // A server away that answers "busy" is back, though resting.
        if !away && let Some(since) = s.away_since.take() {
            return Some(Change::Back(now.saturating_duration_since(since)));
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MAX: Duration = Duration::from_secs(2);
    const MS: Duration = Duration::from_millis(1);

    fn three() -> (Health, Instant) {
        (Health::new(3, MAX, 12345), Instant::now())
    }

    #[test]
    fn picks_in_turn_from_the_first_and_skips_the_failed() {
        let (mut h, t0) = three();
        assert_eq!(h.pick(0, t0), Some(0));
        assert_eq!(h.pick(1, t0), Some(1));
        assert_eq!(h.pick(2, t0), Some(2));
        assert_eq!(h.failed(1, Failure::Away, t0, t0), Some(Change::Away));
        // Server 1 is skipped while it backs off, in favour of the next in turn.
        assert_eq!(h.pick(1, t0 + MS), Some(2));
        assert_eq!(h.pick(0, t0 + MS), Some(0));
        assert!(!h.usable(1, t0 + MS));
        assert!(h.usable(0, t0 + MS) && h.usable(2, t0 + MS));
    }

    #[test]
    fn a_failed_server_is_probed_once_its_back_off_is_over() {
        let (mut h, t0) = three();
        h.failed(0, Failure::Away, t0, t0);
        // The first back-off: 25 ms doubled once, ±50 %: 25 to 75 ms.
        assert!(!h.take(0, t0 + 24 * MS));
        assert!(h.take(0, t0 + 76 * MS), "due again after its back-off");
        // The probe holds it: no second request until it answers.
        assert!(!h.take(0, t0 + 77 * MS));
        assert_eq!(h.pick(0, t0 + 77 * MS), Some(1));
        // A probe that never reports frees it after `max`.
        assert!(h.take(0, t0 + 77 * MS + MAX));
    }

    #[test]
    fn back_offs_grow_with_failures_in_a_row_up_to_the_cap() {
        let (mut h, mut now) = three();
        let mut pauses = Vec::new();
        for _ in 0..12 {
            h.failed(0, Failure::Away, now, now);
            let due = h.servers[0].not_before.expect("backing off");
            pauses.push(due - now);
            now = due;
            assert!(h.take(0, now), "probed when due");
        }
        for (k, p) in pauses.iter().enumerate() {
            let nominal = (25u64 << (k + 1)).min(2000);
            let ms = p.as_millis() as u64;
            assert!(ms >= nominal / 2 && ms <= nominal * 3 / 2, "{k}: {p:?}");
        }
        assert!(pauses.last().is_some_and(|p| *p <= MAX * 3 / 2));
    }

    #[test]
    fn going_away_and_coming_back_are_reported_once_each() {
        let (mut h, t0) = three();
        assert_eq!(h.answered(0, t0, t0), None, "answering all along");
        assert_eq!(h.failed(0, Failure::Away, t0, t0), Some(Change::Away));
        let due = h.servers[0].not_before.expect("backing off");
        assert!(h.take(0, due));
        assert_eq!(h.failed(0, Failure::Away, due, due + MS), None);
        let back = t0 + Duration::from_secs(5);
        assert_eq!(
            h.answered(0, back, back),
            Some(Change::Back(Duration::from_secs(5)))
        );
        assert_eq!(h.answered(0, back + MS, back + MS), None);
        assert!(h.usable(0, back + MS));
    }

    #[test]
    fn requests_sent_before_a_counted_failure_do_not_lengthen_it() {
        let (mut h, t0) = three();
        // Four requests out at once; the server goes; they fail one after another.
        h.failed(2, Failure::Away, t0, t0 + 10 * MS);
        let due = h.servers[2].not_before;
        for k in 1..4 {
            assert_eq!(h.failed(2, Failure::Away, t0, t0 + (10 + k) * MS), None);
        }
        assert_eq!(h.servers[2].not_before, due);
        assert_eq!(h.servers[2].streak, 1);
    }

    #[test]
    fn an_answer_to_a_request_sent_before_a_counted_failure_does_not_bring_it_back() {
        let (mut h, t0) = three();
        // Two requests out at once; the server dies; one fails, then the other's answer,
        // written before the death, arrives.
        assert_eq!(
            h.failed(1, Failure::Away, t0, t0 + 10 * MS),
            Some(Change::Away)
        );
        let due = h.servers[1].not_before;
        assert_eq!(h.answered(1, t0, t0 + 11 * MS), None);
        assert_eq!(h.servers[1].not_before, due, "still backing off");
        assert!(!h.usable(1, t0 + 11 * MS));
        // The next request's answer, sent after the failure, does.
        let later = t0 + Duration::from_secs(1);
        assert_eq!(
            h.answered(1, later, later),
            Some(Change::Back(later - (t0 + 10 * MS)))
        );
    }

    #[test]
    fn a_busy_server_rests_as_long_as_it_asks_without_going_away() {
        let (mut h, t0) = three();
        let asked = Duration::from_secs(5);
        assert_eq!(h.failed(1, Failure::Busy(asked), t0, t0), None);
        assert!(!h.usable(1, t0 + asked - MS));
        assert!(h.usable(1, t0 + asked));
        assert_eq!(h.pick(1, t0 + MS), Some(2));
        // A server that was away and answers "busy" is back, though resting.
        h.failed(0, Failure::Away, t0, t0);
        let later = t0 + Duration::from_secs(1);
        assert_eq!(
            h.failed(0, Failure::Busy(asked), later, later),
            Some(Change::Back(Duration::from_secs(1)))
        );
        assert!(!h.usable(0, later + asked - MS));
    }

    #[test]
    fn busy_answers_without_a_wait_still_back_off() {
        let (mut h, t0) = three();
        let mut now = t0;
        for _ in 0..6 {
            h.failed(0, Failure::Busy(Duration::ZERO), now, now);
            assert!(!h.usable(0, now), "a zero Retry-After is no tight loop");
            now = h.servers[0].not_before.expect("resting");
        }
        // The sixth pause is 1.6 s ±50 %.
        assert!(now - t0 >= Duration::from_millis(1500), "{:?}", now - t0);
    }

    #[test]
    fn the_next_due_moment_is_the_earliest_back_off_end_when_none_is_usable() {
        let (mut h, t0) = three();
        h.failed(0, Failure::Busy(Duration::from_secs(9)), t0, t0);
        h.failed(1, Failure::Busy(Duration::from_secs(3)), t0, t0);
        assert_eq!(h.next_due(t0), None, "server 2 may be asked");
        h.failed(2, Failure::Busy(Duration::from_secs(6)), t0, t0);
        assert_eq!(h.next_due(t0), Some(t0 + Duration::from_secs(3)));
        assert_eq!(h.pick(0, t0 + Duration::from_secs(3)), Some(1));
    }

    #[test]
    fn one_server_behaves_as_a_list_of_one() {
        let mut h = Health::new(1, MAX, 7);
        let t0 = Instant::now();
        assert_eq!(h.pick(0, t0), Some(0));
        h.failed(0, Failure::Away, t0, t0);
        assert_eq!(h.pick(0, t0), None);
        let due = h.next_due(t0).expect("backing off");
        assert_eq!(h.pick(0, due), Some(0));
        assert_eq!(h.pick(0, due), None, "reserved for its probe");
    }
}
