-- 0029: what lets an update keep the textures of the tiles it did not change. Every textures run records, per
-- tile, a fingerprint of everything texturing reads for it (its band and error, its features' rows and meshes,
-- the openings of its LOD2 buildings, the stage's settings and code) with the counts of what it wrote. An
-- update copies the tiles' pages, UVs and failures aside (tex.kept_*) before the stages above empty them; the
-- textures stage then copies back those of every unit whose tiles all have the same fingerprint again, and
-- textures the others. The kept copies are emptied once used.
CREATE TABLE tex.tile_input (
    level       smallint NOT NULL,
    x           integer  NOT NULL,
    y           integer  NOT NULL,
    fingerprint text,
    n_pages     integer  NOT NULL,
    n_uvs       integer  NOT NULL,
    n_failures  integer  NOT NULL,
    PRIMARY KEY (level, x, y)
);
COMMENT ON TABLE tex.tile_input IS 'Per tile of the last textures run: the fingerprint of its input and the rows it wrote (what an update compares to keep a tile''s textures).';
COMMENT ON COLUMN tex.tile_input.level IS 'Tile level.';
COMMENT ON COLUMN tex.tile_input.x IS 'Tile column.';
COMMENT ON COLUMN tex.tile_input.y IS 'Tile row.';
COMMENT ON COLUMN tex.tile_input.fingerprint IS 'sha256 of everything texturing read for the tile (NULL: its unit was lost, never kept).';
COMMENT ON COLUMN tex.tile_input.n_pages IS 'tex.page rows written for the tile.';
COMMENT ON COLUMN tex.tile_input.n_uvs IS 'tex.feature_uv rows written for the tile.';
COMMENT ON COLUMN tex.tile_input.n_failures IS 'tex.failure rows written for the tile.';

CREATE UNLOGGED TABLE tex.kept_page (LIKE tex.page INCLUDING DEFAULTS INCLUDING COMMENTS);
ALTER TABLE tex.kept_page ALTER COLUMN bytes SET STORAGE EXTERNAL;
CREATE INDEX ON tex.kept_page (level, x, y);
CREATE UNLOGGED TABLE tex.kept_feature_uv (LIKE tex.feature_uv INCLUDING DEFAULTS INCLUDING COMMENTS);
CREATE INDEX ON tex.kept_feature_uv (level, x, y);
CREATE UNLOGGED TABLE tex.kept_failure (LIKE tex.failure INCLUDING COMMENTS);
CREATE INDEX ON tex.kept_failure (level, x, y);
COMMENT ON TABLE tex.kept_page IS 'tex.page as it was when an update started (emptied by the textures stage that uses it).';
COMMENT ON TABLE tex.kept_feature_uv IS 'tex.feature_uv as it was when an update started (emptied by the textures stage that uses it).';
COMMENT ON TABLE tex.kept_failure IS 'tex.failure as it was when an update started (emptied by the textures stage that uses it).';
