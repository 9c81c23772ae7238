-- tiles.tile_digests()
-- Every tile with an md5 of its row as the tiles stage writes it (leaf or not, counts, cell, region, content
-- URI, height, band). The tiles stage compares these before and after its run: the tiles whose digest differs,
-- and those whose placements (tiles.building_tile) differ, are what it changed (core/changes.py).
-- Example: SELECT * FROM tiles.tile_digests() LIMIT 5;
CREATE OR REPLACE FUNCTION tiles.tile_digests()
RETURNS TABLE (level smallint, x integer, y integer, digest text)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT t.level, t.x, t.y,
           md5(ROW(t.is_leaf, t.n_features, t.n_triangles, t.cell, t.mesh_region, t.content_uri, t.height,
                   t.gen_level)::text)
    FROM tiles.tile t
$$;
COMMENT ON FUNCTION tiles.tile_digests() IS
    'Every tile and an md5 of its row as the tiles stage writes it: compared before and after the stage to find the tiles it changed.';
