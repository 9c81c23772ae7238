-- tiles.building_tiles_below(level, x, y) -> the tiles.building_tile row of every feature below tile (level, x, y)
-- The one definition of "below a tile", for api.buildings_for_tile, the generalize stage and the hierarchy's
-- checks: candidates from the GiST index of the anchor points (the bounding box of the tile's cell), then exactly
-- by quadtree arithmetic (a leaf (L, X, Y) is below (l, x, y) when L >= l, X >> (L - l) = x and Y >> (L - l) = y).
-- Example: SELECT count(*), count(DISTINCT group_id) FROM tiles.building_tiles_below(0, 0, 0);
CREATE OR REPLACE FUNCTION tiles.building_tiles_below(level integer, x integer, y integer)
RETURNS SETOF tiles.building_tile
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT bt.*
    FROM tiles.tile t
    JOIN tiles.building_tile bt
      ON bt.anchor && t.cell AND bt.level >= t.level
     AND (bt.x >> (bt.level - t.level)) = t.x AND (bt.y >> (bt.level - t.level)) = t.y
    WHERE t.level = $1 AND t.x = $2 AND t.y = $3
$$;
COMMENT ON FUNCTION tiles.building_tiles_below(integer, integer, integer) IS
    'The tiles.building_tile rows of every feature (building or part) in the subtree of tile (level, x, y). Example: SELECT count(*) FROM tiles.building_tiles_below(0, 0, 0);';
