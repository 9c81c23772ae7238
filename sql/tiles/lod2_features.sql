-- tiles.lod2_features(level, x, y, only_groups DEFAULT NULL) -> the LOD2 rows of api.buildings_for_tile
-- Every building and part below tile (level, x, y) at LOD2, its decimated mesh where decimation paid
-- (gen.building_mesh, gen_level 3); with only_groups, just the buildings (outline ids, tiles.building_tile
-- group_id) listed: the landmarks api.buildings_for_tile keeps at LOD2 in the coarser bands. One definition
-- for the LOD2 band and the landmarks, so the two never drift apart; rows are api.feature, as
-- api.buildings_for_tile's. Inlined into its caller (LANGUAGE sql, STABLE, not STRICT).
-- Example: SELECT feature_kind, count(*) FROM tiles.lod2_features(3, 4, 2) GROUP BY 1;
CREATE OR REPLACE FUNCTION tiles.lod2_features(level integer, x integer, y integer,
                                               only_groups bigint[] DEFAULT NULL)
RETURNS SETOF api.feature  -- migrations/0020_feature_type.sql
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT b.kind, b.id, b.osm_type::text, b.osm_id, b.kind,
           coalesce(p.osm_type, b.osm_type)::text, coalesce(p.osm_id, b.osm_id),
           coalesce(b.name, p.name), coalesce(b.building, p.building),
           m.height, m.min_height, b.levels, m.roof_shape,
           b.building_colour, coalesce(b.roof_colour, p.roof_colour),
           coalesce(b.building_material, p.building_material), b.roof_material,
           2::smallint, 3::smallint, 1, d.total_error_m,
           coalesce(d.n_triangles, m.n_triangles), m.roof_height, coalesce(d.semantics, m.semantics),
           coalesce(d.geom, m.geom), coalesce(d.mesh_md5, m.mesh_md5)  -- NULL together with d.geom
    FROM tiles.building_tiles_below($1, $2, $3) bt
    JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod = 2
    JOIN gen.building_mesh d ON d.building_id = bt.building_id AND d.gen_level = 3
    JOIN osm.building b ON b.id = bt.building_id
    LEFT JOIN osm.building p ON p.id = b.parent_id
    WHERE $4 IS NULL OR bt.group_id = ANY($4)
$$;
COMMENT ON FUNCTION tiles.lod2_features(integer, integer, integer, bigint[]) IS
    'LOD2 features (decimated where it paid) of every building below tile (level, x, y), or of the buildings (outline ids) in only_groups: the rows of api.buildings_for_tile''s LOD2 band and of the landmarks it keeps at LOD2. Example: SELECT count(*) FROM tiles.lod2_features(0, 0, 0);';
