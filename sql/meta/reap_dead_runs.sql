-- meta.reap_dead_runs(lock_namespace) -> the run_ids it recorded as failed
-- A running stage process holds the session advisory lock (lock_namespace, run_id) for its whole life
-- (etl/runs.py): PostgreSQL releases it when the process' connection ends, however it ends. A run still
-- 'running' whose lock is free has therefore died (kill -9, an out-of-memory kill, a server restart) without
-- recording its end: it becomes 'failed', finished at its last heartbeat (started_at when it never beat), with
-- that in its error. Taking the lock for this transaction only (pg_try_advisory_xact_lock) also keeps two
-- reapers from recording the same run twice. Called when a stage starts.
-- Example: SELECT * FROM meta.reap_dead_runs(1668050788);
CREATE OR REPLACE FUNCTION meta.reap_dead_runs(lock_namespace integer)
RETURNS SETOF bigint
LANGUAGE sql VOLATILE
AS $$
    UPDATE meta.pipeline_run r
    SET status = 'failed',
        finished_at = coalesce(r.heartbeat_at, r.started_at),
        duration_s = extract(epoch FROM coalesce(r.heartbeat_at, r.started_at) - r.started_at),
        error = format('died without recording its end (killed, or the database server restarted); last seen '
                       'alive at %s', coalesce(r.heartbeat_at, r.started_at))
    WHERE r.status = 'running' AND pg_try_advisory_xact_lock(lock_namespace, r.run_id::integer)
    RETURNING r.run_id
$$;
COMMENT ON FUNCTION meta.reap_dead_runs(integer) IS
    'Records as failed every running pipeline run whose stage process is gone (its advisory lock free), finished at its last heartbeat; returns their run_ids. Called when a stage starts. Example: SELECT * FROM meta.reap_dead_runs(1668050788);';
