-- api.quadtree_root() -> the root region of the quadtree (radians) and the edge of its square on the ground
-- What the exporter writes as the implicit root's bounding region: every tile (level, x, y) is this region
-- halved level times in longitude and latitude (tiles.cell_region), the cell its buildings were placed in.
-- Example: SELECT * FROM api.quadtree_root();
CREATE OR REPLACE FUNCTION api.quadtree_root()
RETURNS TABLE (west double precision, south double precision, east double precision, north double precision,
               size_m double precision)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT g.west, g.south, g.east, g.north, g.size FROM tiles.grid g
$$;
COMMENT ON FUNCTION api.quadtree_root() IS
    'The quadtree''s root region (west, south, east, north in radians; every tile is its implicit-tiling subdivision) and the edge of that square on the ground (m). Example: SELECT * FROM api.quadtree_root();';
