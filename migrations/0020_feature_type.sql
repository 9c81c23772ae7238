-- 0020: api.feature, the row of a tile's content, defined once: api.buildings_for_tile returns it and
-- tiles.lod2_features (its LOD2 band and the landmarks it keeps at LOD2) too, so the two can never drift apart.
-- A type is state (functions returning it depend on it), so it lives here; the functions in sql/ use it.
CREATE TYPE api.feature AS (
    feature_kind      text,
    building_id       bigint,
    osm_type          text,
    osm_id            bigint,
    kind              text,
    building_osm_type text,
    building_osm_id   bigint,
    name              text,
    building          text,
    height            real,
    min_height        real,
    levels            real,
    roof_shape        text,
    building_colour   text,
    roof_colour       text,
    building_material text,
    roof_material     text,
    lod               smallint,
    gen_level         smallint,
    n_members         integer,
    error_m           real,
    n_triangles       integer,
    roof_height       real,
    semantics         bytea,
    geom              geometry
);
COMMENT ON TYPE api.feature IS 'One feature of a tile''s content (a building or part at LOD1/2/3, or a block): the rows of api.buildings_for_tile and tiles.lod2_features, what the exporter writes into a glb.';
COMMENT ON COLUMN api.feature.feature_kind IS 'building (an outline), part (building:part) or block (buildings merged, gen.block).';
COMMENT ON COLUMN api.feature.building_id IS 'osm.building.id of a building or part; gen.block.block_id of a block.';
COMMENT ON COLUMN api.feature.osm_type IS 'W way, R relation, B block.';
COMMENT ON COLUMN api.feature.osm_id IS 'OSM id of the way or relation; block_id for a block.';
COMMENT ON COLUMN api.feature.kind IS 'osm.building.kind (building or part); block for a block.';
COMMENT ON COLUMN api.feature.building_osm_type IS 'osm_type of the outline a part belongs to (the feature''s own for an outline or block).';
COMMENT ON COLUMN api.feature.building_osm_id IS 'osm_id of the outline a part belongs to (the feature''s own for an outline or block).';
COMMENT ON COLUMN api.feature.name IS 'name=* (the outline''s when a part has none).';
COMMENT ON COLUMN api.feature.building IS 'building=* (the outline''s when a part has none).';
COMMENT ON COLUMN api.feature.height IS 'Top above ground (m) of the mesh drawn.';
COMMENT ON COLUMN api.feature.min_height IS 'Bottom above ground (m) of the mesh drawn.';
COMMENT ON COLUMN api.feature.levels IS 'building:levels.';
COMMENT ON COLUMN api.feature.roof_shape IS 'Roof shape drawn (flat below LOD2 and for blocks).';
COMMENT ON COLUMN api.feature.building_colour IS 'building:colour (#rrggbb).';
COMMENT ON COLUMN api.feature.roof_colour IS 'roof:colour (#rrggbb), the outline''s when a part has none.';
COMMENT ON COLUMN api.feature.building_material IS 'building:material, the outline''s when a part has none.';
COMMENT ON COLUMN api.feature.roof_material IS 'roof:material.';
COMMENT ON COLUMN api.feature.lod IS 'Level of detail of the mesh: 0 block, 1 simplified solid, 2 roofs, 3 facades.';
COMMENT ON COLUMN api.feature.gen_level IS 'Generalization level (gen.tolerance): 1 and below blocks, 2 simplified, 3 LOD2, 4 LOD3.';
COMMENT ON COLUMN api.feature.n_members IS 'Buildings merged into the feature (1 unless a block).';
COMMENT ON COLUMN api.feature.error_m IS 'Bound on the distance (m) to the full-detail LOD3 model.';
COMMENT ON COLUMN api.feature.n_triangles IS 'Triangles of the mesh.';
COMMENT ON COLUMN api.feature.roof_height IS 'Roof height (m) of the mesh drawn (0 when flat).';
COMMENT ON COLUMN api.feature.semantics IS 'One lod.surface_type byte per triangle of geom (ground, wall, roof, window, door).';
COMMENT ON COLUMN api.feature.geom IS 'The mesh: POLYHEDRALSURFACE Z of triangles in the working CRS, z metres above ground.';
