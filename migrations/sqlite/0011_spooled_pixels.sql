-- Tile pixels move out of SQLite into a file per job beside the database (`spool.rs`).
-- A row of a spooled tile keeps an empty `rgb` and the CRC-32 of the tile's bytes in its
-- job's spool file; `crc` NULL means the pixels are in `rgb` (an in-memory database, which
-- has no folder for a spool, and rows stored before this migration).
ALTER TABLE tile_pixels ADD COLUMN crc INTEGER;
