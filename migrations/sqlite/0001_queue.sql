-- The render queue: jobs, their uploaded assets, their tiles under lease, tile pixels as they
-- arrive, and the assembled PNG. Times are integer milliseconds since the Unix epoch, computed
-- in Rust and bound as parameters, so the SQL stays portable.

CREATE TABLE jobs (
    id           TEXT PRIMARY KEY,
    seq          INTEGER NOT NULL UNIQUE,          -- submission order (FIFO scheduling)
    state        TEXT NOT NULL CHECK (state IN ('queued', 'running', 'done', 'failed', 'cancelled')),
    scene        TEXT NOT NULL,                    -- the .ray text as submitted
    name         TEXT,                             -- the uploaded file name, when there was one
    width        INTEGER NOT NULL,
    height       INTEGER NOT NULL,
    tile         INTEGER NOT NULL,                 -- tile edge in pixels
    sampler      TEXT,                             -- per-job sampler override (NULL: the scene's)
    samples      INTEGER,
    threshold    REAL,
    tiles_total  INTEGER NOT NULL,
    tiles_done   INTEGER NOT NULL DEFAULT 0,
    error        TEXT,                             -- why a job failed, for its user
    created_at   INTEGER NOT NULL,
    started_at   INTEGER,
    finished_at  INTEGER,
    png_bytes    INTEGER                           -- size of the assembled PNG once done
);

CREATE TABLE assets (
    job_id  TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    name    TEXT NOT NULL,
    bytes   BLOB NOT NULL,
    PRIMARY KEY (job_id, name)
);

-- One row per tile. `lease` is the fencing token of the current claim: renewals, results,
-- failures and releases carry it and are accepted only while it matches. `attempt` counts
-- claims; `failures` counts reported failures and lost leases, and a tile whose failures
-- reach the service's attempt limit fails its job.
CREATE TABLE tiles (
    job_id         TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    idx            INTEGER NOT NULL,
    x              INTEGER NOT NULL,
    y              INTEGER NOT NULL,
    w              INTEGER NOT NULL,
    h              INTEGER NOT NULL,
    state          TEXT NOT NULL CHECK (state IN ('queued', 'leased', 'done')),
    attempt        INTEGER NOT NULL DEFAULT 0,
    lease          TEXT,                      -- current (or, once done, completing) lease token
    worker         TEXT,
    lease_expires  INTEGER,
    failures       INTEGER NOT NULL DEFAULT 0,
    last_error     TEXT,
    PRIMARY KEY (job_id, idx)
);
-- The claim walks active jobs in submission order and takes each one's first queued tile.
CREATE INDEX tiles_by_state ON tiles (job_id, state, idx);
CREATE INDEX jobs_by_state ON jobs (state, seq);
-- The reaper finds expired leases without scanning every tile ever stored.
CREATE INDEX tiles_leased ON tiles (state, lease_expires);

CREATE TABLE tile_pixels (
    job_id  TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    idx     INTEGER NOT NULL,
    rgb     BLOB NOT NULL,                         -- w × h × 3 sRGB bytes, row-major
    PRIMARY KEY (job_id, idx)
);

-- A worker that keeps failing a job is kept away from it until `until`.
CREATE TABLE keep_away (
    job_id    TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    worker    TEXT NOT NULL,
    failures  INTEGER NOT NULL DEFAULT 0,
    until     INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (job_id, worker)
);

-- The assembled PNG in chunks, so that neither assembly nor download holds it whole.
CREATE TABLE image_chunks (
    job_id  TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    seq     INTEGER NOT NULL,
    bytes   BLOB NOT NULL,
    PRIMARY KEY (job_id, seq)
);
