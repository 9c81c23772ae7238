-- meta.changes_since(p_run, p_producers)
-- What the runs of the stages p_producers changed since run p_run began: one row per such run that ended
-- after that or has not ended, with what it recorded in meta.run_dirty (recorded false: it recorded nothing,
-- so it may have changed anything). core/changes.py unions the rows; a stage reads only the tiles they reach.
-- Example: SELECT * FROM meta.changes_since(42, ARRAY['ingest', 'lod']);
CREATE OR REPLACE FUNCTION meta.changes_since(p_run bigint, p_producers text[])
RETURNS TABLE (run_id bigint, recorded boolean, building_ids bigint[], levels integer[], xs integer[],
               ys integer[])
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT r.run_id, d.run_id IS NOT NULL, d.building_ids, d.levels, d.xs, d.ys
    FROM meta.pipeline_run r LEFT JOIN meta.run_dirty d USING (run_id)
    WHERE r.stage = ANY(p_producers)
      AND (r.finished_at IS NULL
           OR r.finished_at >= (SELECT s.started_at FROM meta.pipeline_run s WHERE s.run_id = p_run))
$$;
COMMENT ON FUNCTION meta.changes_since(bigint, text[]) IS
    'The runs of the stages p_producers since run p_run began, with what each recorded it changed (meta.run_dirty; recorded false: it may have changed anything).';
