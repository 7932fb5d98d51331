//! The reaper's charging rule, shared by every backend: which of one worker's expired leases
//! on one job count a failure against their tile, and how many stalls the worker is counted.
//! Pure: the backends read the leases and write the outcome in their own SQL.
//!
//! A worker's leases on one job that run out within `stall_ms` of each other are one stall,
//! in one pass or across passes: one stall counted for the worker, apart from the failures it
//! reports, and never a reason to keep it away. A failure is charged to each tile it said it
//! was rendering (a renewal with `rendering`), one per thread of a worker of many; the tiles it held ahead go back uncharged. A worker that
//! stalled before renewing anything said nothing: then the tile whose lease ran out first
//! is charged (its held-ahead tiles were claimed later). Counted once a tile, one pause or
//! crash of a lone worker would be two stalls, and tiles never begun would run out of
//! attempts.

/// One expired lease, as the rule needs it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Lapse {
    /// When it ran out (ms since the epoch).
    pub expires: i64,
    /// Its holder said it was rendering the tile.
    pub rendering: bool,
}

/// What one worker's stall on one job comes to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Charges {
    /// Per lease, in the order given: whether its tile is charged a failure.
    pub charged: Vec<bool>,
    /// Stalls counted for the worker.
    pub strikes: i64,
    /// The end of its latest stall, to be stored for the next pass.
    pub stall_until: i64,
}

/// Applies the rule to `lapses` (one worker's expired leases on one job, in the order they
/// ran out), given the end of its stall as stored (`stall_until`, 0 for none). `named`:
/// false for leases without a worker name, each then its own stall.
pub(crate) fn charge(
    lapses: &[Lapse],
    mut stall_until: i64,
    stall_ms: i64,
    named: bool,
) -> Charges {
    let mut charged = Vec::with_capacity(lapses.len());
    let mut strikes = 0;
    for (k, t) in lapses.iter().enumerate() {
        let opens = !named || t.expires >= stall_until;
        if opens {
            strikes += 1;
            stall_until = t.expires.saturating_add(stall_ms);
        }
        // Charged: a tile the worker said it was rendering; or, when it said so of none of
        // this stall's tiles (it stopped before its first renewal), the one whose lease ran
        // out first.
        charged.push(
            t.rendering
                || (opens
                    && !lapses[k..]
                        .iter()
                        .take_while(|u| u.expires < stall_until)
                        .any(|u| u.rendering)),
        );
    }
    Charges {
        charged,
        strikes,
        stall_until,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lapse(expires: i64, rendering: bool) -> Lapse {
        Lapse { expires, rendering }
    }

    #[test]
    fn one_stall_is_one_strike_charging_what_was_rendering() {
        let c = charge(
            &[lapse(100, false), lapse(110, true), lapse(120, true)],
            0,
            50,
            true,
        );
        assert_eq!(c.charged, vec![false, true, true]);
        assert_eq!(c.strikes, 1);
        assert_eq!(c.stall_until, 150);
    }

    #[test]
    fn a_worker_that_said_nothing_is_charged_its_first_lease() {
        let c = charge(&[lapse(100, false), lapse(110, false)], 0, 50, true);
        assert_eq!(c.charged, vec![true, false]);
        assert_eq!(c.strikes, 1);
    }

    #[test]
    fn leases_far_apart_are_two_stalls_and_a_stored_stall_goes_on() {
        let c = charge(&[lapse(100, false), lapse(200, false)], 0, 50, true);
        assert_eq!((c.charged, c.strikes), (vec![true, true], 2));
        // Within the stall a previous pass stored: no new strike, nothing charged.
        let c = charge(&[lapse(100, false)], 120, 50, true);
        assert_eq!((c.charged, c.strikes, c.stall_until), (vec![false], 0, 120));
    }

    #[test]
    fn unnamed_leases_are_each_their_own_stall() {
        let c = charge(&[lapse(100, false), lapse(101, false)], 0, 50, false);
        assert_eq!((c.charged, c.strikes), (vec![true, true], 2));
    }
}
