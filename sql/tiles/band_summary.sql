-- tiles.band_summary() -> per band (tiles.tile.gen_level): tiles, features, triangles, largest geometric error
-- What the generalize stage reports per band once the hierarchy is finished.
-- Example: SELECT * FROM tiles.band_summary();
CREATE OR REPLACE FUNCTION tiles.band_summary()
RETURNS TABLE (
    gen_level             smallint,
    tiles                 bigint,
    features              bigint,
    triangles             numeric,
    max_geometric_error_m double precision
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT gen_level, count(*), sum(content_features), sum(content_triangles), max(geometric_error)
    FROM tiles.tile GROUP BY gen_level ORDER BY gen_level
$$;
COMMENT ON FUNCTION tiles.band_summary() IS
    'Per band (gen_level): tiles, content features and triangles, largest geometric error (m). Example: SELECT * FROM tiles.band_summary();';
