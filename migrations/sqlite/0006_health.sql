-- One row that `GET /healthz` rewrites, so that a database that no longer takes writes (a
-- full disk, a lock held elsewhere) makes the health check fail, not only one that cannot
-- be read.
CREATE TABLE health (
    id         INTEGER PRIMARY KEY CHECK (id = 1),
    checked_at INTEGER NOT NULL
);
