-- A failed or cancelled job keeps its stored tiles' pixels until it is deleted, so that a
-- retry (`POST /jobs/{id}/retry`) renders only the tiles that are missing. Only the chunks
-- of a PNG encoded while it rendered go when it ends: a retried job's image is encoded
-- again from its tiles.
DROP TRIGGER job_ended_without_image;
CREATE TRIGGER job_ended_without_image AFTER UPDATE OF state ON jobs
WHEN NEW.state IN ('failed', 'cancelled')
BEGIN
    DELETE FROM image_chunks WHERE job_id = NEW.id;
END;
