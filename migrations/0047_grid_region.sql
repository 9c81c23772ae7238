-- 0047: the quadtree is cut on the implicit subdivision of its root region (issue 45). A 3D Tiles client that
-- ignores the subtrees' TILE_BOUNDING_REGION metadata (3DTilesRendererJS, loaders.gl) computes each tile's volume
-- by halving the root region in longitude and latitude; cells cut square in the working CRS are not those halves
-- (8 of Helsinki's 9 tiles lay up to 353 m outside the volume such a client computed). The grid now holds its
-- root region, and a building's cell at level L is the half-of-a-half of it its anchor falls in. The working-CRS
-- columns stay: origin and size describe the root square in metres (gen.level_for_height reads the cell size).
ALTER TABLE tiles.grid
    ADD COLUMN west  double precision,
    ADD COLUMN south double precision,
    ADD COLUMN east  double precision,
    ADD COLUMN north double precision;
COMMENT ON COLUMN tiles.grid.west IS 'West edge of the root region (rad, WGS84): level L cells halve [west, east] L times.';
COMMENT ON COLUMN tiles.grid.south IS 'South edge of the root region (rad, WGS84).';
COMMENT ON COLUMN tiles.grid.east IS 'East edge of the root region (rad, WGS84).';
COMMENT ON COLUMN tiles.grid.north IS 'North edge of the root region (rad, WGS84): level L cells halve [south, north] L times.';
COMMENT ON COLUMN tiles.grid.origin_x IS 'West edge of the root square (m, working CRS: the root region''s south-west corner).';
COMMENT ON COLUMN tiles.grid.origin_y IS 'South edge of the root square (m, working CRS: the root region''s south-west corner).';
COMMENT ON COLUMN tiles.grid.size IS 'Edge of the root region (m, on the ground at its centre: the region is a square there); level L cells are about size / 2^L.';
COMMENT ON TABLE tiles.grid IS 'The quadtree: the root region [west, east] × [south, north] (radians), square on the ground at its centre, covering every mesh; level L has 2^L × 2^L cells, each the implicit-tiling subdivision of the root (lon and lat halved L times), y growing north. A cell is split while it holds more than max_features features or max_triangles triangles.';
-- every tile's cell is now a bounding box of its lon/lat cell in the working CRS (a GiST filter only)
COMMENT ON COLUMN tiles.tile.cell IS 'The working-CRS envelope of the tile''s cell (its lon/lat cell, reprojected with its edges densified): the GiST filter of tiles.building_tiles_below, the exact test being quadtree arithmetic.';
