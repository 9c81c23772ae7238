-- gen.decimation_input(min_triangles, batch, ids DEFAULT NULL) -> one row per feature (building or part) of
-- the tile quadtree, by batch unit, then id
-- What the generalize stage decimates at level 3: each feature's LOD2 mesh (WKB) and semantics when it has at
-- least min_triangles triangles (NULL otherwise: it is used as it is), its triangle count and heights, and
-- whether its LOD3 mesh has openings (the LOD2-to-LOD3 step of its error bound), and the unit of the batches
-- it goes into (gen.batch_units: the rows of one unit are one batch).
--   min_triangles  settings.gen_decimate_min_triangles
--   batch          settings.gen_batch_features (gen.batch_units)
--   ids            only these features (building ids; NULL: all): an update reads only the batches it
--                  computes again
-- Streamed by a server-side cursor: inlined into the caller's query (LANGUAGE sql, STABLE, not STRICT).
-- Example: SELECT count(*), count(mesh) FROM gen.decimation_input(64, 2000);
CREATE OR REPLACE FUNCTION gen.decimation_input(min_triangles integer, batch integer, ids bigint[] DEFAULT NULL)
RETURNS TABLE (
    building_id bigint,
    n_triangles integer,
    min_height  real,
    height      real,
    mesh        bytea,
    semantics   bytea,
    openings    boolean,
    unit_level  smallint,
    unit_x      integer,
    unit_y      integer
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT m.building_id, m.n_triangles, m.min_height, m.height,
           CASE WHEN m.n_triangles >= $1 THEN ST_AsBinary(m.geom) END,
           CASE WHEN m.n_triangles >= $1 THEN m.semantics END,
           m3.n_windows + m3.n_doors > 0, u.unit_level, u.unit_x, u.unit_y
    FROM tiles.building_tile bt
    JOIN gen.batch_units($2) u ON (u.level, u.x, u.y) = (bt.level, bt.x, bt.y)
    JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod = 2
    JOIN lod.building_mesh m3 ON m3.building_id = bt.building_id AND m3.lod = 3
    WHERE $3 IS NULL OR bt.building_id = ANY($3)
    ORDER BY u.unit_level, u.unit_x, u.unit_y, m.building_id
$$;
COMMENT ON FUNCTION gen.decimation_input(integer, integer, bigint[]) IS
    'Features for the level-3 decimation: LOD2 mesh (WKB) and semantics when they have at least min_triangles triangles, triangle count, heights, LOD3 openings, batch unit (gen.batch_units); by unit, then id. Example: SELECT count(mesh) FROM gen.decimation_input(64, 2000);';
