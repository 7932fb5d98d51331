-- A failed or cancelled job keeps its stored tiles' pixels until it is deleted, so that a
-- retry (`POST /jobs/{id}/retry`) renders only the tiles that are missing. Only the chunks
-- of a PNG encoded while it rendered go when it ends: a retried job's image is encoded
-- again from its tiles.
CREATE OR REPLACE FUNCTION tessera_job_ended_without_image() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    DELETE FROM image_chunks WHERE job_id = NEW.id;
    RETURN NULL;
END
$$;
