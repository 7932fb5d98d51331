-- The tiles of one band of rows, in tile order: what the PNG encoder reads for each band.
--
-- Without it the band query (`Queue::band`) found a job's tiles by `job_id` alone, kept
-- those of the band, and sorted the rows, pixels included, in a temporary B-tree: every
-- tile's pixels were copied once more into the sorter (about 4 ms of SQLite's thread per
-- 1920×1080 job, `perf`). With the band's rows found by `(job_id, y)` and already in `idx`
-- order, which is left to right within a band, nothing is sorted.
CREATE INDEX tiles_by_band ON tiles (job_id, y, idx);
