-- A job's scene text in a table of its own. In the `jobs` row it came before most of the
-- columns every listing reads, and SQLite reads a row's columns in order: a listing of jobs
-- with 10 MB scenes walked each scene's overflow pages to reach the columns after it
-- (`GET /jobs?limit=50` took 150–180 ms against 1 ms, and the web page asks every second).
CREATE TABLE job_scenes (
    job_id TEXT PRIMARY KEY NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    scene  TEXT NOT NULL
);
INSERT INTO job_scenes (job_id, scene) SELECT id, scene FROM jobs;
ALTER TABLE jobs DROP COLUMN scene;
