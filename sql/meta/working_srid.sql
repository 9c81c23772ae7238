-- meta.working_srid() -> integer
-- SRID of the metric working CRS of the loaded dataset (meta.dataset.srid); every *_local geometry and every
-- lod mesh uses it. NULL before the first ingest.
-- Example: SELECT ST_Transform(ST_SetSRID(ST_MakePoint(24.95, 60.17), 4326), meta.working_srid());
CREATE OR REPLACE FUNCTION meta.working_srid()
RETURNS integer
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT srid FROM meta.dataset
$$;
COMMENT ON FUNCTION meta.working_srid() IS 'SRID of the working CRS of the loaded dataset (meta.dataset.srid).';
