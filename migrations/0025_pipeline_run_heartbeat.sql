-- 0025: a run's last sign of life. A stage process updates heartbeat_at every few seconds while it works and
-- holds a session advisory lock on its run for as long as it lives (etl/runs.py), so a run killed with
-- kill -9, or cut off by a server restart, is found the next time any stage starts (meta.reap_dead_runs) and
-- recorded as failed at its last heartbeat, instead of staying 'running' for ever.
ALTER TABLE meta.pipeline_run ADD COLUMN heartbeat_at timestamptz;
COMMENT ON COLUMN meta.pipeline_run.heartbeat_at IS 'Last time the running stage process said it was alive (every few seconds); a run that died is recorded as failed with finished_at = this.';
COMMENT ON COLUMN meta.pipeline_run.status IS 'running while the stage works; ok or failed when it ended. A run whose process died (kill -9, a server restart) is failed the next time a stage starts, with finished_at its last heartbeat.';
