-- What a worker says of itself (its threads, the rays it traced per second lately) and
-- when it said goodbye (`POST /worker/bye`), for `GET /workers` and the metrics.
-- NULL: not said. `left_at` 0: never left; a worker has left while `left_at` is at least
-- its `last_seen` (a claim after the goodbye brings it back).
ALTER TABLE workers ADD COLUMN threads INTEGER;
ALTER TABLE workers ADD COLUMN rays_per_second REAL;
ALTER TABLE workers ADD COLUMN left_at INTEGER NOT NULL DEFAULT 0;
