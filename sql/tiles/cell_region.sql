-- tiles.cell_region(level, x, y) -> {west, south, east, north} (radians) of quadtree cell (level, x, y)
-- The implicit-tiling subdivision of the grid's root region (tiles.grid): longitude and latitude halved `level`
-- times, x growing east and y north. It is the volume a 3D Tiles client computes for tile (level, x, y) when it
-- ignores the subtrees' metadata, and the cell tiles.build_quadtree places a building in by its anchor.
-- Example: SELECT tiles.cell_region(1, 0, 1);
CREATE OR REPLACE FUNCTION tiles.cell_region(level integer, x integer, y integer)
RETURNS double precision[]
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT ARRAY[g.west + (g.east - g.west) * $2 / 2 ^ $1, g.south + (g.north - g.south) * $3 / 2 ^ $1,
                 g.west + (g.east - g.west) * ($2 + 1) / 2 ^ $1, g.south + (g.north - g.south) * ($3 + 1) / 2 ^ $1]
    FROM tiles.grid g
$$;
COMMENT ON FUNCTION tiles.cell_region(integer, integer, integer) IS
    'West, south, east, north (radians) of quadtree cell (level, x, y): the root region of tiles.grid halved level times in longitude and latitude, as implicit tiling subdivides it. Example: SELECT tiles.cell_region(1, 0, 1);';
