-- tiles.cell_envelope(level, x, y) -> the working-CRS bounding box of quadtree cell (level, x, y)
-- A cell is a rectangle in longitude and latitude (tiles.cell_region); in the working CRS its parallels bow (by
-- ~30 m over a 30 km cell at 60° N), so its edges are densified to ~1/64 of the cell before reprojection, and the
-- box grown by 1 m for what remains. tiles.building_tiles_below takes its GiST candidates from this box.
-- Example: SELECT ST_AsText(tiles.cell_envelope(0, 0, 0));
CREATE OR REPLACE FUNCTION tiles.cell_envelope(level integer, x integer, y integer)
RETURNS geometry
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT ST_Expand(ST_Envelope(ST_Transform(
               ST_Segmentize(ST_MakeEnvelope(degrees(r[1]), degrees(r[2]), degrees(r[3]), degrees(r[4]), 4326),
                             degrees(r[4] - r[2]) / 64),
               g.srid)), 1.0)
    FROM tiles.grid g CROSS JOIN tiles.cell_region($1, $2, $3) r
$$;
COMMENT ON FUNCTION tiles.cell_envelope(integer, integer, integer) IS
    'Working-CRS bounding box (grown by 1 m) of quadtree cell (level, x, y), whose lon/lat rectangle is tiles.cell_region: the GiST filter for what lies in a tile. Example: SELECT ST_AsText(tiles.cell_envelope(0, 0, 0));';
