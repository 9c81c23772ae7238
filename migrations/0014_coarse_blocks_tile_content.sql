-- 0014: blocks above the thesis' coarsest level, and every tile's content listed in a table.
-- A city larger than a few tiles has tiles above height 4; they used to repeat the 10 m blocks of level 0, so
-- the root of a 1M-building city held every block of it (~380k features). Their gen_level now goes below 0
-- (gen.level_for_height), each a step of gen.tolerance: 20 m, 40 m, ... blocks aggregated from the tile's
-- children's content, so a coarse tile holds about as many features as a fine one.
-- the band now also depends on the tile's width (sql/gen/level_for_height.sql, reloaded after this)
DROP FUNCTION IF EXISTS gen.level_for_height(integer, integer);
ALTER TABLE gen.block DROP CONSTRAINT block_gen_level_check;
ALTER TABLE gen.block ADD CONSTRAINT block_gen_level_check CHECK (gen_level <= 1);
COMMENT ON COLUMN gen.block.gen_level IS 'Generalization level: aggregation distance and outline tolerance are gen.tolerance(gen_level): 10 m at 0, 5 m at 1, doubling for each level below 0 (blocks merged from the tile''s children''s blocks and buildings).';
COMMENT ON COLUMN gen.block.error_m IS 'Measured Hausdorff distance (m) between the block and what it replaces: its members'' simplified solids (gen_level 2) at levels 0 and 1, the blocks and simplified solids of the tile''s children below 0.';
COMMENT ON COLUMN gen.block.total_error_m IS 'Bound on the distance (m) to the full-detail LOD3 models: error_m plus the largest total_error_m of what it replaces.';
COMMENT ON TABLE tiles.tile IS 'Tiles of the quadtree. Every tile has content: leaves LOD3, inner tiles the buildings below them generalized at gen.level_for_height(height, root height, width); children replace their parent (REPLACE).';
COMMENT ON COLUMN tiles.tile.gen_level IS 'Generalization level of the content, from the height: 4 LOD3 (leaves), 3 LOD2, 2 simplified LOD1, 1 and 0 blocks at 5 m and 10 m, below 0 blocks at 20 m, 40 m, ... (gen.tolerance, gen.level_for_height of height, root height and width).';

-- One row per feature of every tile's content, as api.buildings_for_tile returns it without the meshes:
-- what api.lod_for_view lists for a tile, read by one index scan. Filled by the generalize stage
-- (tiles.finish_hierarchy); emptied by the tiles stage with the tiles.
CREATE TABLE tiles.tile_content (
    level        smallint NOT NULL,
    x            integer  NOT NULL,
    y            integer  NOT NULL,
    feature_kind text     NOT NULL,
    feature_id   bigint   NOT NULL,
    osm_type     text     NOT NULL,
    osm_id       bigint   NOT NULL,
    lod          smallint NOT NULL,
    gen_level    smallint NOT NULL,
    n_members    integer  NOT NULL,
    n_triangles  integer  NOT NULL,
    error_m      real     NOT NULL,
    PRIMARY KEY (level, x, y, feature_kind, feature_id),
    FOREIGN KEY (level, x, y) REFERENCES tiles.tile (level, x, y) ON DELETE CASCADE
);
COMMENT ON TABLE tiles.tile_content IS 'Every feature of every tile''s content (api.buildings_for_tile without meshes and properties), for api.lod_for_view and analysts: which tile draws which building or block at which LOD. Filled by the generalize stage.';
COMMENT ON COLUMN tiles.tile_content.level IS 'Tile level.';
COMMENT ON COLUMN tiles.tile_content.x IS 'Tile column.';
COMMENT ON COLUMN tiles.tile_content.y IS 'Tile row.';
COMMENT ON COLUMN tiles.tile_content.feature_kind IS 'building, part or block.';
COMMENT ON COLUMN tiles.tile_content.feature_id IS 'osm.building.id of a building or part, gen.block.block_id of a block.';
COMMENT ON COLUMN tiles.tile_content.osm_type IS 'OSM type of the feature (N/W/R), B for a block.';
COMMENT ON COLUMN tiles.tile_content.osm_id IS 'OSM id of the feature; block_id for a block.';
COMMENT ON COLUMN tiles.tile_content.lod IS 'LOD drawn: 0 block, 1 simplified solid, 2 roofs, 3 facades.';
COMMENT ON COLUMN tiles.tile_content.gen_level IS 'Generalization level of the feature (gen.tolerance).';
COMMENT ON COLUMN tiles.tile_content.n_members IS 'Buildings the feature stands for (1 unless a block).';
COMMENT ON COLUMN tiles.tile_content.n_triangles IS 'Triangles of the feature''s mesh.';
COMMENT ON COLUMN tiles.tile_content.error_m IS 'Bound on the distance (m) to the full-detail LOD3 models.';
