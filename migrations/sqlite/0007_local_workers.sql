-- The name prefix of the local workers of the service process that last started on this
-- database. A service that starts again (after a crash: SIGKILL, out of memory) knows that
-- those workers died with the process, and requeues the tiles they held without charging a
-- failure; it used to extend their leases and then charge every one of them as a stall.
CREATE TABLE local_workers (
    prefix TEXT PRIMARY KEY NOT NULL
);
