-- A job becomes `running` (and gets its `started_at`) inside the statement that hands out
-- its first tile. It was a second statement after the claim had committed, so a crash or a
-- failed write between the two left a job whose tiles were being rendered `queued`, with no
-- start time, and a claim that failed after its lease was stored (the worker never got the
-- tile, which then sat leased until the lease ran out and was charged as a stall).
--
-- `claimed_at` is the claim's own clock (the service's, which the tests set), written by the
-- claim statement so that the trigger can copy it: SQLite's clock is not the queue's.
ALTER TABLE tiles ADD COLUMN claimed_at INTEGER;

-- On `lease`, which only the claim sets to a value (a result sets `state`, not `lease`): a
-- trigger on `state` was entered for every stored result too, only to find it no claim.
CREATE TRIGGER job_started AFTER UPDATE OF lease ON tiles
WHEN NEW.state = 'leased'
BEGIN
    UPDATE jobs SET state = 'running', started_at = NEW.claimed_at
     WHERE id = NEW.job_id AND state = 'queued';
END;
