-- 0019: textures (stage textures): atlas pages per tile and a UV per triangle corner of every tile feature.
-- The schema tex exists since 0001. Rows hang off tiles.tile: rebuilding the tiles (stage tiles) drops them, so
-- a textured export never uses pages of another tile tree.

CREATE TABLE tex.page (
    level            smallint NOT NULL,
    x                integer  NOT NULL,
    y                integer  NOT NULL,
    page_no          smallint NOT NULL CHECK (page_no >= 0),
    format           text     NOT NULL,
    mime             text     NOT NULL,
    width            integer  NOT NULL CHECK (width > 0),
    height           integer  NOT NULL CHECK (height > 0),
    n_bytes          integer  NOT NULL,
    bytes            bytea    NOT NULL,
    utilization      real     NOT NULL,
    texels_per_metre real     NOT NULL,
    view_distance_m  real     NOT NULL,
    n_charts         integer  NOT NULL,
    n_scaled         integer  NOT NULL,
    padding          smallint NOT NULL,
    rects            bytea    NOT NULL,
    PRIMARY KEY (level, x, y, page_no),
    FOREIGN KEY (level, x, y) REFERENCES tiles.tile (level, x, y) ON DELETE CASCADE
);
-- encoded images do not compress further
ALTER TABLE tex.page ALTER COLUMN bytes SET STORAGE EXTERNAL;
COMMENT ON TABLE tex.page IS 'Texture atlas pages: every chart (wall, roof face, xatlas sheet, flat-colour palette) of a tile''s content packed onto pages of at most tex_page_size texels a side, at the resolution the tile''s view distance needs (etl/textures/stage.py). The exporter gives each page one glTF material. Example: SELECT t.gen_level, count(*) AS pages, sum(p.n_bytes) AS bytes, sum(p.utilization * p.width * p.height) / sum(p.width * p.height) AS utilization FROM tex.page p JOIN tiles.tile t USING (level, x, y) GROUP BY 1 ORDER BY 1;';
COMMENT ON COLUMN tex.page.level IS 'Tile (tiles.tile) the page belongs to: quadtree level.';
COMMENT ON COLUMN tex.page.x IS 'Tile column.';
COMMENT ON COLUMN tex.page.y IS 'Tile row.';
COMMENT ON COLUMN tex.page.page_no IS 'Page of the tile, 0.. (tex.feature_uv.page refers to it).';
COMMENT ON COLUMN tex.page.format IS 'Image format of bytes: webp (OpenImageIO writes no KTX2 here).';
COMMENT ON COLUMN tex.page.mime IS 'Media type of bytes, as the glTF image''s mimeType (image/webp).';
COMMENT ON COLUMN tex.page.width IS 'Page width in texels (cropped to what it holds, a multiple of 4, at most tex_page_size).';
COMMENT ON COLUMN tex.page.height IS 'Page height in texels.';
COMMENT ON COLUMN tex.page.n_bytes IS 'Length of bytes.';
COMMENT ON COLUMN tex.page.bytes IS 'The encoded page (sRGB, no alpha).';
COMMENT ON COLUMN tex.page.utilization IS 'Fraction of the page''s texels inside a chart (gutters and free space excluded): sum of rects'' w × h / (width × height).';
COMMENT ON COLUMN tex.page.texels_per_metre IS 'Resolution of the tile''s charts: max_sse / (geometric error × px_per_texel), capped by tex_max_texels_per_metre (charts too big for a page are shrunk: n_scaled).';
COMMENT ON COLUMN tex.page.view_distance_m IS 'Nearest camera distance (m) at which texels_per_metre is not magnified for the assumed view (tex_fov_deg, tex_screen_height): where the tile is replaced by its children, or the cap''s distance.';
COMMENT ON COLUMN tex.page.n_charts IS 'Charts on the page (rects holds their boxes).';
COMMENT ON COLUMN tex.page.n_scaled IS 'Charts shrunk below texels_per_metre to fit on a page (walls longer than the page).';
COMMENT ON COLUMN tex.page.padding IS 'Gutter texels around each chart, filled with its edge texels.';
COMMENT ON COLUMN tex.page.rects IS 'Content box of each chart on the page: int32 little-endian (x, y, w, h) in texels from the top-left corner, n_charts of them.';

CREATE TABLE tex.feature_uv (
    level        smallint NOT NULL,
    x            integer  NOT NULL,
    y            integer  NOT NULL,
    feature_kind text     NOT NULL,
    feature_id   bigint   NOT NULL,
    n_triangles  integer  NOT NULL,
    page         bytea    NOT NULL,
    uv           bytea    NOT NULL,
    PRIMARY KEY (level, x, y, feature_kind, feature_id),
    FOREIGN KEY (level, x, y) REFERENCES tiles.tile (level, x, y) ON DELETE CASCADE,
    CHECK (length(page) = 2 * n_triangles AND length(uv) = 24 * n_triangles)
);
COMMENT ON TABLE tex.feature_uv IS 'Texture coordinates of every textured feature of a tile, per triangle corner in the triangle order of the feature''s mesh as api.buildings_for_tile(level, x, y) returns it (the order the exporter decodes): the exporter keeps a triangle''s corners as distinct vertices wherever their UVs differ. A feature without a row is drawn with vertex colours (tex.failure says why).';
COMMENT ON COLUMN tex.feature_uv.level IS 'Tile: quadtree level.';
COMMENT ON COLUMN tex.feature_uv.x IS 'Tile column.';
COMMENT ON COLUMN tex.feature_uv.y IS 'Tile row.';
COMMENT ON COLUMN tex.feature_uv.feature_kind IS 'api.buildings_for_tile.feature_kind (building, part, block).';
COMMENT ON COLUMN tex.feature_uv.feature_id IS 'api.buildings_for_tile.building_id (osm.building.id, or gen.block.block_id for a block).';
COMMENT ON COLUMN tex.feature_uv.n_triangles IS 'Triangles of the mesh the UVs were made for; the exporter refuses UVs whose count differs from the mesh it writes (stale textures).';
COMMENT ON COLUMN tex.feature_uv.page IS 'tex.page.page_no of each triangle: int16 little-endian, n_triangles of them.';
COMMENT ON COLUMN tex.feature_uv.uv IS 'Page coordinates of each triangle corner: float32 little-endian (u, v) × 3 per triangle, glTF convention ((0, 0) the page''s top-left corner, v down), inside the chart''s box on the page.';

CREATE TABLE tex.failure (
    failure_id   bigint   GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    level        smallint NOT NULL,
    x            integer  NOT NULL,
    y            integer  NOT NULL,
    feature_kind text     NOT NULL,
    feature_id   bigint   NOT NULL,
    osm_type     text     NOT NULL,
    osm_id       bigint   NOT NULL,
    reason       text     NOT NULL,
    detail       text,
    created_at   timestamptz NOT NULL DEFAULT now(),
    FOREIGN KEY (level, x, y) REFERENCES tiles.tile (level, x, y) ON DELETE CASCADE
);
CREATE INDEX failure_tile_idx ON tex.failure (level, x, y);
COMMENT ON TABLE tex.failure IS 'Tile features the textures stage could not texture (they keep their vertex colours; nothing is dropped). For every run: features in the tiles = rows of tex.feature_uv + rows here.';
COMMENT ON COLUMN tex.failure.failure_id IS 'Row number.';
COMMENT ON COLUMN tex.failure.level IS 'Tile: quadtree level.';
COMMENT ON COLUMN tex.failure.x IS 'Tile column.';
COMMENT ON COLUMN tex.failure.y IS 'Tile row.';
COMMENT ON COLUMN tex.failure.feature_kind IS 'api.buildings_for_tile.feature_kind.';
COMMENT ON COLUMN tex.failure.feature_id IS 'api.buildings_for_tile.building_id.';
COMMENT ON COLUMN tex.failure.osm_type IS 'W, R, or B for a block (osm_id is then the block id).';
COMMENT ON COLUMN tex.failure.osm_id IS 'OSM id of the way or relation (the block id for a block).';
COMMENT ON COLUMN tex.failure.reason IS 'Stable code: texturing_failed (the feature fails alone), tile_texturing_failed (the tile failed without it too).';
COMMENT ON COLUMN tex.failure.detail IS 'The error.';
COMMENT ON COLUMN tex.failure.created_at IS 'When the stage recorded it (UTC).';
