-- The end of a worker's current stall on a job: leases of that worker on that job that run
-- out before it belong to a stall already counted (one strike, one tile charged), see
-- `Queue::reap`. A worker's leases (the tile it renders and the one it holds ahead) run
-- out up to a renewal period apart and were reaped in two passes: two strikes, enough to
-- keep a lone worker away and fail its job, and a failure charged to a tile it had not
-- begun.
ALTER TABLE keep_away ADD COLUMN stall_until INTEGER NOT NULL DEFAULT 0;
