-- Whether the tile's current holder has said it is rendering it (a renewal with
-- `rendering=true`), as opposed to holding it ahead in its queue. When a worker stalls, the
-- reaper charges a failure to each tile it was rendering, and to none it only held; see
-- `Queue::reap`. Reset whenever the tile is handed out.
ALTER TABLE tiles ADD COLUMN rendering INTEGER NOT NULL DEFAULT 0;
