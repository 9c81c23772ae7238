-- gen.decimation_input(min_triangles) -> one row per feature (building or part) of the tile quadtree, in id order
-- What the generalize stage decimates at level 3: each feature's LOD2 mesh (WKB) and semantics when it has at
-- least min_triangles triangles (NULL otherwise: it is used as it is), its triangle count and heights, and
-- whether its LOD3 mesh has openings (the LOD2-to-LOD3 step of its error bound).
--   min_triangles  settings.gen_decimate_min_triangles
-- Streamed by a server-side cursor: inlined into the caller's query (LANGUAGE sql, STABLE, not STRICT).
-- Example: SELECT count(*), count(mesh) FROM gen.decimation_input(64);
CREATE OR REPLACE FUNCTION gen.decimation_input(min_triangles integer)
RETURNS TABLE (
    building_id bigint,
    n_triangles integer,
    min_height  real,
    height      real,
    mesh        bytea,
    semantics   bytea,
    openings    boolean
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT m.building_id, m.n_triangles, m.min_height, m.height,
           CASE WHEN m.n_triangles >= $1 THEN ST_AsBinary(m.geom) END,
           CASE WHEN m.n_triangles >= $1 THEN m.semantics END,
           m3.n_windows + m3.n_doors > 0
    FROM tiles.building_tile bt
    JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod = 2
    JOIN lod.building_mesh m3 ON m3.building_id = bt.building_id AND m3.lod = 3
    ORDER BY m.building_id
$$;
COMMENT ON FUNCTION gen.decimation_input(integer) IS
    'Features for the level-3 decimation: LOD2 mesh (WKB) and semantics when they have at least min_triangles triangles, triangle count, heights, LOD3 openings; id order. Example: SELECT count(mesh) FROM gen.decimation_input(64);';
