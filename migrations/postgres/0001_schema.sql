-- The farm's state on PostgreSQL: the same tables as the SQLite schema reaches after its
-- migrations, for several service processes on one database. Times are milliseconds since
-- the Unix epoch, computed by the service and bound as integers.

CREATE TABLE jobs (
    id           TEXT PRIMARY KEY,
    -- Submission order (FIFO among equal priorities): a sequence, since several
    -- replicas insert at once.
    seq          BIGINT GENERATED ALWAYS AS IDENTITY UNIQUE,
    state        TEXT NOT NULL CHECK (state IN ('queued', 'running', 'done', 'failed', 'cancelled')),
    name         TEXT,
    width        BIGINT NOT NULL,
    height       BIGINT NOT NULL,
    tile         BIGINT NOT NULL,
    sampler      TEXT,
    samples      BIGINT,
    threshold    DOUBLE PRECISION,
    tiles_total  BIGINT NOT NULL,
    tiles_done   BIGINT NOT NULL DEFAULT 0,
    error        TEXT,
    created_at   BIGINT NOT NULL,
    started_at   BIGINT,
    finished_at  BIGINT,
    png_bytes    BIGINT,
    priority     BIGINT NOT NULL DEFAULT 0
);
CREATE INDEX jobs_to_claim ON jobs (priority DESC, seq) WHERE state IN ('queued', 'running');

CREATE TABLE job_scenes (
    job_id TEXT PRIMARY KEY REFERENCES jobs(id) ON DELETE CASCADE,
    scene  TEXT NOT NULL
);

CREATE TABLE assets (
    job_id  TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    name    TEXT NOT NULL,
    bytes   BYTEA NOT NULL,
    PRIMARY KEY (job_id, name)
);

CREATE TABLE tiles (
    job_id         TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    idx            BIGINT NOT NULL,
    x              BIGINT NOT NULL,
    y              BIGINT NOT NULL,
    w              BIGINT NOT NULL,
    h              BIGINT NOT NULL,
    state          TEXT NOT NULL CHECK (state IN ('queued', 'leased', 'done')),
    attempt        BIGINT NOT NULL DEFAULT 0,
    lease          TEXT,
    worker         TEXT,
    lease_expires  BIGINT,
    failures       BIGINT NOT NULL DEFAULT 0,
    last_error     TEXT,
    rendering      BOOLEAN NOT NULL DEFAULT FALSE,
    claimed_at     BIGINT,
    PRIMARY KEY (job_id, idx)
);
CREATE INDEX tiles_by_state ON tiles (job_id, state, idx);
CREATE INDEX tiles_by_band ON tiles (job_id, y, idx);
CREATE INDEX tiles_leased ON tiles (lease_expires) WHERE state = 'leased';

-- Pixels are written once and read once; noisy renders barely compress, so they are kept
-- out of line without trying (STORAGE EXTERNAL), as are the PNG's chunks.
CREATE TABLE tile_pixels (
    job_id  TEXT NOT NULL,
    idx     BIGINT NOT NULL,
    rgb     BYTEA NOT NULL,
    PRIMARY KEY (job_id, idx),
    FOREIGN KEY (job_id, idx) REFERENCES tiles (job_id, idx) ON DELETE CASCADE
);
ALTER TABLE tile_pixels ALTER COLUMN rgb SET STORAGE EXTERNAL;

CREATE TABLE keep_away (
    job_id       TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    worker       TEXT NOT NULL,
    failures     BIGINT NOT NULL DEFAULT 0,
    until        BIGINT NOT NULL DEFAULT 0,
    stall_until  BIGINT NOT NULL DEFAULT 0,
    PRIMARY KEY (job_id, worker)
);

CREATE TABLE image_chunks (
    job_id  TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    seq     BIGINT NOT NULL,
    bytes   BYTEA NOT NULL,
    PRIMARY KEY (job_id, seq)
);
ALTER TABLE image_chunks ALTER COLUMN bytes SET STORAGE EXTERNAL;

-- A job that ends without an image drops its partial pixels and image.
CREATE FUNCTION tessera_job_ended_without_image() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    DELETE FROM tile_pixels WHERE job_id = NEW.id;
    DELETE FROM image_chunks WHERE job_id = NEW.id;
    RETURN NULL;
END
$$;
CREATE TRIGGER job_ended_without_image AFTER UPDATE OF state ON jobs
    FOR EACH ROW WHEN (NEW.state IN ('failed', 'cancelled') AND OLD.state IS DISTINCT FROM NEW.state)
    EXECUTE FUNCTION tessera_job_ended_without_image();

-- The storage-health row: when a replica last wrote it, and when a replica last saw the
-- database refuse a write for its storage's sake.
CREATE TABLE health (
    id                 INTEGER PRIMARY KEY CHECK (id = 1),
    checked_at         BIGINT NOT NULL,
    storage_failed_at  BIGINT
);

-- Leases whose renewal or result a replica refused while the database failed, shared so
-- that whichever replica reaps extends them (see the store's `health`).
CREATE TABLE heard_leases (
    lease     TEXT PRIMARY KEY,
    heard_at  BIGINT NOT NULL
);

CREATE TABLE workers (
    name                TEXT PRIMARY KEY,
    last_seen           BIGINT NOT NULL,
    claims              BIGINT NOT NULL DEFAULT 0,
    claims_with_results BIGINT NOT NULL DEFAULT 0,
    tiles_done          BIGINT NOT NULL DEFAULT 0
);
CREATE INDEX workers_by_last_seen ON workers (last_seen);
