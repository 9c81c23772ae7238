-- gen.tolerance(gen_level) -> metres
-- The one function that sets every generalization level's tolerance, as OpenMapTiles' ZRes sets a zoom's
-- pixel size: 10 m at level 0 (the thesis' coarsest aggregation distance), halving with each finer level,
-- doubling with each coarser one (levels below 0 are the tiles above a city's height-4 tiles); 0 at level 4,
-- the full-detail LOD3. What each level holds:
--  -1, -2, ..  blocks: the tile's children's blocks and buildings closer than 20 m, 40 m, ... merged
--   0  blocks: buildings closer than 10 m merged, outlines simplified at 10 m
--   1  blocks: buildings closer than 5 m merged, outlines simplified at 5 m
--   2  LOD1: each building (with its parts) one solid on its footprint simplified at 2.5 m
--   3  LOD2: roofs; meshes decimated where the measured error stays within 1.25 m
--   4  LOD3: facades (windows, doors), no generalization
-- In every block band (<= 1) a block within the tolerance of one point (sqrt(radius² + height²)) is omitted from
-- its tile (selection; gen.block.omitted), and so is one within its tile's geometric error
-- (tiles.omit_within_error).
-- Example: SELECT g, gen.tolerance(g) FROM generate_series(-2, 4) g;
CREATE OR REPLACE FUNCTION gen.tolerance(gen_level integer)
RETURNS double precision
LANGUAGE sql IMMUTABLE PARALLEL SAFE STRICT
AS $$
    SELECT CASE WHEN gen_level >= 4 THEN 0.0 ELSE 10.0 / 2.0 ^ gen_level END
$$;
COMMENT ON FUNCTION gen.tolerance(integer) IS
    'Tolerance (m) of generalization level g <= 4, 10 / 2^g: aggregation distance and outline tolerance of blocks (g <= 1), footprint tolerance (2), decimation error limit (3), 0 for LOD3 (4). Example: SELECT gen.tolerance(0); -- 10';
