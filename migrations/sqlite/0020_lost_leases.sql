-- Leases a worker lost on a job by stopping answering (stalls), counted apart from the
-- failures it reported: a worker restarted under its name is not evidence against it, so
-- only `failures` keeps it away. A stall still charges the tile it was rendering.
ALTER TABLE keep_away ADD COLUMN stalls INTEGER NOT NULL DEFAULT 0;
