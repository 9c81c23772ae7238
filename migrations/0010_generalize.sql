-- 0010: generalization (stage generalize) and one multi-LOD tile hierarchy.
ALTER TABLE osm.building ADD COLUMN protected boolean NOT NULL DEFAULT false;
COMMENT ON COLUMN osm.building.protected IS 'Protected from aggregation (a landmark; set by the landmarks stage): simplified once, never merged into a block.';

-- Simplified footprints of whole buildings (an outline with its parts): the LOD1 band of the tileset.
CREATE TABLE gen.footprint (
    building_id     bigint PRIMARY KEY REFERENCES osm.building (id) ON DELETE CASCADE,
    geom            geometry(MultiPolygon) NOT NULL,
    tolerance_m     real    NOT NULL,
    n_vertices_in   integer NOT NULL,
    n_vertices_out  integer NOT NULL,
    area_in_m2      double precision NOT NULL,
    area_out_m2     double precision NOT NULL,
    error_m         real    NOT NULL,
    status          text    NOT NULL
);
COMMENT ON TABLE gen.footprint IS 'Footprint of every building (outline with its parts) simplified at gen.tolerance(2): vertex importance (angle × edge lengths) and the Sester–Brenner short-edge rules (etl/generalize/simplify.py).';
COMMENT ON COLUMN gen.footprint.building_id IS 'osm.building.id of the outline (a building and its parts are one footprint here).';
COMMENT ON COLUMN gen.footprint.geom IS 'Simplified footprint in the working CRS; valid; vertices shared with touching neighbours kept.';
COMMENT ON COLUMN gen.footprint.tolerance_m IS 'Simplification tolerance used (m), gen.tolerance(2).';
COMMENT ON COLUMN gen.footprint.n_vertices_in IS 'Distinct vertices before simplification.';
COMMENT ON COLUMN gen.footprint.n_vertices_out IS 'Distinct vertices after simplification.';
COMMENT ON COLUMN gen.footprint.area_in_m2 IS 'Footprint area before (m²).';
COMMENT ON COLUMN gen.footprint.area_out_m2 IS 'Footprint area after (m²).';
COMMENT ON COLUMN gen.footprint.error_m IS 'Measured Hausdorff distance (m) between the original and the simplified outline.';
COMMENT ON COLUMN gen.footprint.status IS 'simplified, unchanged, or kept_original with the reason (area change above the limit, invalid result, ...).';

-- Generalized meshes per building and generalization level: 2 = the simplified footprint extruded to the
-- area-weighted height of the building (its LOD1 band); 3 = its LOD2 mesh decimated (only where that pays).
CREATE TABLE gen.building_mesh (
    building_id     bigint   NOT NULL REFERENCES osm.building (id) ON DELETE CASCADE,
    gen_level       smallint NOT NULL CHECK (gen_level IN (2, 3)),
    geom            geometry(PolyhedralSurfaceZ),
    semantics       bytea,
    n_triangles     integer  NOT NULL,
    n_triangles_in  integer  NOT NULL,
    min_height      real     NOT NULL,
    height          real     NOT NULL,
    error_m         real     NOT NULL,
    total_error_m   real     NOT NULL,
    status          text     NOT NULL,
    PRIMARY KEY (building_id, gen_level)
);
ALTER TABLE gen.building_mesh ALTER COLUMN geom SET COMPRESSION lz4;
COMMENT ON TABLE gen.building_mesh IS 'Generalized meshes: gen_level 2 = simplified footprint extruded (one per building with its parts), 3 = LOD2 decimated (fast-simplification) where decimation stayed within gen.tolerance(3); every feature has a gen_level 3 row with its errors, geom NULL where LOD2 is used unchanged.';
COMMENT ON COLUMN gen.building_mesh.building_id IS 'osm.building.id: the outline for gen_level 2, the feature (building or part) for 3.';
COMMENT ON COLUMN gen.building_mesh.gen_level IS 'Generalization level (gen.tolerance(gen_level) is its tolerance).';
COMMENT ON COLUMN gen.building_mesh.geom IS 'Closed triangulated solid, POLYHEDRALSURFACE Z, working CRS, z above ground. NULL at gen_level 3 where the LOD2 mesh is used as it is (too small to decimate, or decimation did not pay).';
COMMENT ON COLUMN gen.building_mesh.semantics IS 'One lod.surface_type code per triangle.';
COMMENT ON COLUMN gen.building_mesh.n_triangles IS 'Triangles in geom.';
COMMENT ON COLUMN gen.building_mesh.n_triangles_in IS 'Triangles of what it replaces (the LOD2 meshes of the building and its parts).';
COMMENT ON COLUMN gen.building_mesh.min_height IS 'Bottom above ground (m).';
COMMENT ON COLUMN gen.building_mesh.height IS 'Top above ground (m); area-weighted over the parts for gen_level 2.';
COMMENT ON COLUMN gen.building_mesh.error_m IS 'Measured Hausdorff distance (m) to what it replaces: the LOD2 meshes of the building and its parts.';
COMMENT ON COLUMN gen.building_mesh.total_error_m IS 'Bound on the distance (m) to the full-detail LOD3 model: error_m plus the LOD2-to-LOD3 step (openings depth).';
COMMENT ON COLUMN gen.building_mesh.status IS 'How it was made, or why the source was kept (decimation error above tolerance, not closed, ...).';

-- Blocks: neighbouring buildings of one tile's subtree merged (buffer-union-unbuffer) and extruded flat.
CREATE TABLE gen.block (
    block_id        bigint   GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    level           smallint NOT NULL,
    x               integer  NOT NULL,
    y               integer  NOT NULL,
    gen_level       smallint NOT NULL CHECK (gen_level IN (0, 1)),
    members         bigint[] NOT NULL,
    n_members       integer  NOT NULL,
    footprint       geometry(MultiPolygon) NOT NULL,
    geom            geometry(PolyhedralSurfaceZ) NOT NULL,
    semantics       bytea    NOT NULL,
    n_triangles     integer  NOT NULL,
    height          real     NOT NULL,
    error_m         real     NOT NULL,
    total_error_m   real     NOT NULL,
    FOREIGN KEY (level, x, y) REFERENCES tiles.tile (level, x, y) ON DELETE CASCADE
);
ALTER TABLE gen.block ALTER COLUMN geom SET COMPRESSION lz4;
CREATE INDEX block_tile_idx ON gen.block (level, x, y);
CREATE INDEX block_footprint_idx ON gen.block USING gist (footprint);
CREATE INDEX block_members_idx ON gen.block USING gin (members);
COMMENT ON TABLE gen.block IS 'Aggregated blocks: the buildings of one coarse tile closer than gen.tolerance(gen_level) merged into one flat-roofed solid. Protected buildings are never members.';
COMMENT ON COLUMN gen.block.block_id IS 'Block id (also the feature id in the tile glb).';
COMMENT ON COLUMN gen.block.level IS 'Tile level (the block is content of tile (level, x, y)).';
COMMENT ON COLUMN gen.block.x IS 'Tile column.';
COMMENT ON COLUMN gen.block.y IS 'Tile row.';
COMMENT ON COLUMN gen.block.gen_level IS 'Generalization level: aggregation distance and outline tolerance are gen.tolerance(gen_level).';
COMMENT ON COLUMN gen.block.members IS 'osm.building.id of the member buildings (outlines).';
COMMENT ON COLUMN gen.block.n_members IS 'Number of member buildings.';
COMMENT ON COLUMN gen.block.footprint IS 'Merged and simplified outline in the working CRS.';
COMMENT ON COLUMN gen.block.geom IS 'The block solid (flat roof), POLYHEDRALSURFACE Z, working CRS.';
COMMENT ON COLUMN gen.block.semantics IS 'One lod.surface_type code per triangle.';
COMMENT ON COLUMN gen.block.n_triangles IS 'Triangles in geom.';
COMMENT ON COLUMN gen.block.height IS 'Roof height above ground (m): the members'' heights weighted by their footprint areas.';
COMMENT ON COLUMN gen.block.error_m IS 'Measured Hausdorff distance (m) between the block and what it replaces (its members'' simplified solids, gen_level 2).';
COMMENT ON COLUMN gen.block.total_error_m IS 'Bound on the distance (m) to the full-detail LOD3 models: error_m plus the largest total_error_m of its members.';

-- The tile hierarchy: every tile has content now (REPLACE refinement), its band decided by its height.
ALTER TABLE tiles.tile
    ADD COLUMN height             smallint,
    ADD COLUMN gen_level          smallint,
    ADD COLUMN content_features   integer,
    ADD COLUMN content_triangles  bigint,
    ADD COLUMN content_error_m    double precision,
    ADD COLUMN box                double precision[] CHECK (box IS NULL OR cardinality(box) = 12);
COMMENT ON COLUMN tiles.tile.height IS 'Levels down to the deepest leaf below (0 for a leaf).';
COMMENT ON COLUMN tiles.tile.gen_level IS 'Generalization level of the content, from the height: 4 LOD3 (leaves), 3 LOD2, 2 simplified LOD1, 1 and 0 blocks (gen.tolerance).';
COMMENT ON COLUMN tiles.tile.content_features IS 'Features (blocks, buildings, parts) in this tile''s own content.';
COMMENT ON COLUMN tiles.tile.content_triangles IS 'Triangles in this tile''s own content.';
COMMENT ON COLUMN tiles.tile.content_error_m IS 'Largest total_error_m of the content (m): how far it may be from the full-detail models.';
COMMENT ON COLUMN tiles.tile.box IS 'Oriented bounding box of the region in ECEF: centre (3) and three half-axes (9), m; what api.lod_for_view measures distances to.';

ALTER TABLE tiles.building_tile
    ADD COLUMN group_id bigint,
    ADD COLUMN anchor   geometry(Point);
CREATE INDEX building_tile_anchor_idx ON tiles.building_tile USING gist (anchor);
COMMENT ON COLUMN tiles.building_tile.group_id IS 'osm.building.id of the outline the feature belongs to (itself for an outline).';
COMMENT ON COLUMN tiles.building_tile.anchor IS 'The point that placed the building in the quadtree (centre of its outline''s bounding box), working CRS.';
ALTER TABLE tiles.tile ALTER COLUMN geometric_error DROP NOT NULL;
COMMENT ON COLUMN tiles.tile.geometric_error IS '3D Tiles geometricError (m), measured: the larger of content_error_m and the children''s geometric errors (0 for leaves). NULL until the generalize stage has run.';
COMMENT ON COLUMN tiles.tile.content_uri IS 'URI of the tile''s glb content relative to tileset.json (every tile has content: REPLACE refinement).';
COMMENT ON COLUMN tiles.tile.region IS '3D Tiles bounding region of the content in this tile and below (every band: LOD meshes, generalized meshes, blocks): west, south, east, north (radians, WGS84), min and max height (m above the ellipsoid).';
COMMENT ON TABLE tiles.tile IS 'Tiles of the quadtree. Every tile has content: leaves LOD3, inner tiles the buildings below them generalized at gen.level_for_height(height); children replace their parent (REPLACE).';
