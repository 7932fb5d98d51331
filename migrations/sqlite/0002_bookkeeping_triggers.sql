-- Bookkeeping that follows from one change, done by SQLite within the statement that makes
-- the change, so that it cannot be forgotten by one of the statements that make it.
--
-- A result is stored by one statement (`INSERT INTO tile_pixels … SELECT … WHERE` the lease
-- is current), so that storing it is one round trip to SQLite instead of a transaction of
-- five. The rest of the bookkeeping follows from the insert, inside the same statement and
-- so atomically with it: the tile is done and its job counts one more tile.
--
-- The queue's insert (`Queue::complete`) is the only writer of `tile_pixels`, and it inserts
-- only under the tile's current lease. Its `RETURNING` clause reads `jobs.tiles_done` as it
-- was before this trigger ran (SQLite computes `RETURNING` before AFTER triggers), so the
-- last tile of a job sees `tiles_done + 1 = tiles_total`; the queue tests pin that exactly
-- one result of a job is its last.
CREATE TRIGGER tile_pixels_stored AFTER INSERT ON tile_pixels
BEGIN
    UPDATE tiles SET state = 'done', lease_expires = NULL
     WHERE job_id = NEW.job_id AND idx = NEW.idx;
    UPDATE jobs SET tiles_done = tiles_done + 1 WHERE id = NEW.job_id;
END;

-- A job that ends without an image (failed, cancelled) drops its stored pixels and any
-- chunks of a PNG encoded while it rendered, whichever statement ended it.
CREATE TRIGGER job_ended_without_image AFTER UPDATE OF state ON jobs
WHEN NEW.state IN ('failed', 'cancelled')
BEGIN
    DELETE FROM tile_pixels WHERE job_id = NEW.id;
    DELETE FROM image_chunks WHERE job_id = NEW.id;
END;
