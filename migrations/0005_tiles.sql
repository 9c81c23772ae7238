-- 0005: the quadtree of tiles and the building -> tile assignment.
CREATE TABLE tiles.grid (
    singleton   boolean PRIMARY KEY DEFAULT true CHECK (singleton),
    srid        integer NOT NULL,
    origin_x    double precision NOT NULL,
    origin_y    double precision NOT NULL,
    size        double precision NOT NULL,
    max_features  integer NOT NULL,
    max_triangles integer NOT NULL,
    max_level   integer NOT NULL
);
COMMENT ON COLUMN tiles.grid.singleton IS 'Always true: the table holds one row.';
COMMENT ON COLUMN tiles.grid.srid IS 'Working CRS of the grid (meta.dataset.srid).';
COMMENT ON COLUMN tiles.grid.origin_x IS 'West edge of the level-0 cell (m, working CRS).';
COMMENT ON COLUMN tiles.grid.origin_y IS 'South edge of the level-0 cell (m, working CRS).';
COMMENT ON COLUMN tiles.grid.size IS 'Edge length of the level-0 cell (m); level L cells are size / 2^L.';
COMMENT ON COLUMN tiles.grid.max_features IS 'Split budget: most features (meshes) a leaf may hold, unless it holds one building.';
COMMENT ON COLUMN tiles.grid.max_triangles IS 'Split budget: most triangles a leaf may hold, unless it holds one building.';
COMMENT ON COLUMN tiles.grid.max_level IS 'Deepest level; cells there are leaves whatever they hold.';
COMMENT ON TABLE tiles.grid IS 'The quadtree: level-0 cell is the square [origin_x, origin_x + size] × [origin_y, origin_y + size] in the working CRS; level L has 2^L × 2^L cells, y growing north. A cell is split while it holds more than max_features features or max_triangles triangles.';

CREATE TABLE tiles.tile (
    level           smallint NOT NULL,
    x               integer  NOT NULL,
    y               integer  NOT NULL,
    is_leaf         boolean  NOT NULL,
    n_features      integer  NOT NULL,
    n_triangles     bigint   NOT NULL,
    cell            geometry(Polygon) NOT NULL,
    region          double precision[] NOT NULL CHECK (cardinality(region) = 6),
    geometric_error double precision NOT NULL,
    content_uri     text,
    PRIMARY KEY (level, x, y)
);
COMMENT ON TABLE tiles.tile IS 'Tiles of the quadtree. Only leaves have content (every building is in exactly one leaf); inner tiles bound their subtree.';
COMMENT ON COLUMN tiles.tile.level IS 'Quadtree level, 0 = root.';
COMMENT ON COLUMN tiles.tile.x IS 'Column, 0 at origin_x.';
COMMENT ON COLUMN tiles.tile.y IS 'Row, 0 at origin_y (south).';
COMMENT ON COLUMN tiles.tile.is_leaf IS 'True when the tile has content and no children.';
COMMENT ON COLUMN tiles.tile.n_features IS 'Features (building and part meshes) in this tile and its descendants.';
COMMENT ON COLUMN tiles.tile.n_triangles IS 'Triangles in this tile and its descendants.';
COMMENT ON COLUMN tiles.tile.cell IS 'The quadtree cell in the working CRS. Buildings are assigned by the centre of their outline, so content may overhang the cell (a loose quadtree); region bounds it exactly.';
COMMENT ON COLUMN tiles.tile.region IS '3D Tiles bounding region of the content in this tile and below: west, south, east, north (radians, WGS84), min and max height (m above the ellipsoid).';
COMMENT ON COLUMN tiles.tile.geometric_error IS '3D Tiles geometricError (m): 0 for leaves; for inner tiles the cell edge length × tile_ge_factor.';
COMMENT ON COLUMN tiles.tile.content_uri IS 'URI of the glb content relative to tileset.json (leaves only).';

CREATE TABLE tiles.building_tile (
    building_id bigint   PRIMARY KEY REFERENCES osm.building (id) ON DELETE CASCADE,
    level       smallint NOT NULL,
    x           integer  NOT NULL,
    y           integer  NOT NULL,
    FOREIGN KEY (level, x, y) REFERENCES tiles.tile (level, x, y) ON DELETE CASCADE
);
COMMENT ON COLUMN tiles.building_tile.building_id IS 'osm.building.id of the feature (building or part).';
COMMENT ON COLUMN tiles.building_tile.level IS 'Level of its leaf tile.';
COMMENT ON COLUMN tiles.building_tile.x IS 'Column of its leaf tile.';
COMMENT ON COLUMN tiles.building_tile.y IS 'Row of its leaf tile.';
CREATE INDEX building_tile_tile_idx ON tiles.building_tile (level, x, y);
COMMENT ON TABLE tiles.building_tile IS 'The leaf tile of every building and part with a mesh. A part is in the tile of its outline, so a building is never split across tiles.';
