-- The workers the service has heard from: what `GET /workers` lists, and which workers
-- are live when the reaper fails a job that every live worker is kept away from. In the
-- database, not in a service process's memory, so that every process on the database
-- answers from the same roster and a restart keeps it.
CREATE TABLE workers (
    name                TEXT PRIMARY KEY,
    -- Milliseconds since the Unix epoch, from the service's clock.
    last_seen           INTEGER NOT NULL,
    claims              INTEGER NOT NULL DEFAULT 0,
    -- Of those claims, the ones that came back with a posted result (`?next=`).
    claims_with_results INTEGER NOT NULL DEFAULT 0,
    tiles_done          INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX workers_by_last_seen ON workers (last_seen);
