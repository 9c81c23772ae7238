-- api.textures_stale() -> boolean: the textures were made from content that has changed since
-- True when tex.page holds pages and no textures run succeeded, or the last successful one is older than the
-- last successful lod, tiles or generalize run (meta.pipeline_run): the meshes and tiles the textures were
-- laid out on may be gone. The exporter refuses such textures.
-- Example: SELECT api.textures_stale();
CREATE OR REPLACE FUNCTION api.textures_stale()
RETURNS boolean
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT EXISTS (SELECT 1 FROM tex.page)
           AND (tex_run IS NULL OR (gen_run IS NOT NULL AND tex_run < gen_run))
    FROM (SELECT (SELECT max(run_id) FROM meta.pipeline_run WHERE stage = 'textures' AND status = 'ok') AS tex_run,
                 (SELECT max(run_id) FROM meta.pipeline_run
                  WHERE stage IN ('lod', 'tiles', 'generalize') AND status = 'ok') AS gen_run) r
$$;
COMMENT ON FUNCTION api.textures_stale() IS
    'True when tex.page holds textures older than the last successful lod, tiles or generalize run (or made by no successful textures run): the exporter refuses them. Example: SELECT api.textures_stale();';
