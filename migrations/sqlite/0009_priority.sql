-- A job's priority: claims take tiles of the highest-priority job that has one queued, and
-- first in, first out among jobs of one priority (0 unless the submission says otherwise).
-- A quick preview submitted behind a long render waited for the render's last tile to be
-- handed out. The partial index holds the queued and running jobs only, in claim order, so
-- that a claim does not read the rows of every job that ever ran.
ALTER TABLE jobs ADD COLUMN priority INTEGER NOT NULL DEFAULT 0;
CREATE INDEX jobs_to_claim ON jobs (priority DESC, seq) WHERE state IN ('queued', 'running');
