-- api.export_features(level, x, y, single_lod DEFAULT NULL, base_height DEFAULT 0) -> what the exporter
-- writes into tile (level, x, y)'s glb, one row per feature
-- api.buildings_for_tile's features (with single_lod, a single-LOD tileset's) with their meshes lifted by
-- base_height and transformed to ECEF (EPSG:4978, z = height above the ellipsoid) as WKB, their landmark
-- level (lm.building.level: local, where the city-wide rank changes in every tile with any edit), and the
-- landmark exaggeration metadata of lm.exaggeration_role, as the landmarks stage stored it in lm.exaggeration
-- (role 1 a landmark, 2 a building its scaled footprint would cover, 0 neither; intervals, footprint circle,
-- gap, and the landmark's and the building's ground centres in ECEF as WKB points). Blocks have no level and
-- no role. Rows in api.buildings_for_tile's order; the columns up to semantics are api.feature's
-- (migrations/0020).
--   level, x, y  the tile
--   single_lod   1, 2 or 3: every building of a leaf at that LOD (NULL: the tile's band)
--   base_height  metres added to every z (settings.base_height_m)
-- Example: SELECT feature_kind, lod, lm_role, count(*) FROM api.export_features(0, 0, 0) GROUP BY 1, 2, 3;
CREATE OR REPLACE FUNCTION api.export_features(level integer, x integer, y integer, single_lod integer DEFAULT NULL,
                                               base_height double precision DEFAULT 0)
RETURNS TABLE (
    feature_kind       text,
    building_id        bigint,
    osm_type           text,
    osm_id             bigint,
    kind               text,
    building_osm_type  text,
    building_osm_id    bigint,
    name               text,
    building           text,
    height             real,
    min_height         real,
    levels             real,
    roof_shape         text,
    building_colour    text,
    roof_colour        text,
    building_material  text,
    roof_material      text,
    lod                smallint,
    gen_level          smallint,
    n_members          integer,
    error_m            real,
    semantics          bytea,
    ecef_wkb           bytea,
    lm_level           smallint,
    lm_role            integer,
    lm_landmark_osm_id bigint,
    lm_scale_from_m    real,
    lm_scale_step      real,
    lm_max_scale       real,
    lm_radius_m        real,
    lm_gap_m           double precision,
    lm_centre_wkb      bytea,
    lm_own_wkb         bytea
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT f.feature_kind, f.building_id, f.osm_type, f.osm_id, f.kind, f.building_osm_type, f.building_osm_id,
           f.name, f.building, f.height, f.min_height, f.levels, f.roof_shape, f.building_colour, f.roof_colour,
           f.building_material, f.roof_material, f.lod, f.gen_level, f.n_members, f.error_m, f.semantics,
           ST_AsBinary(ST_Transform(ST_Translate(f.geom, 0, 0, $5), 4978)),
           l.level, coalesce(x.role, 0), lo.osm_id,
           coalesce(x.scale_from_m, 0), coalesce(x.scale_step, 0), coalesce(x.max_scale, 1),
           coalesce(x.landmark_radius_m, 0), coalesce(x.gap_m, 0),
           ST_AsBinary(ST_Transform(ST_Translate(ST_Force3D(x.landmark_centroid), 0, 0, $5), 4978)),
           ST_AsBinary(ST_Transform(ST_Translate(ST_Force3D(x.centroid), 0, 0, $5), 4978))
    FROM api.buildings_for_tile($1, $2, $3, $4) f
    LEFT JOIN osm.building o ON f.kind <> 'block' AND o.id = f.building_id
    LEFT JOIN lm.building l ON l.building_id = coalesce(o.parent_id, o.id)
    LEFT JOIN lm.exaggeration x ON x.building_id = l.building_id
    LEFT JOIN osm.building lo ON lo.id = x.landmark_id
$$;
COMMENT ON FUNCTION api.export_features(integer, integer, integer, integer, double precision) IS
    'What the exporter writes into tile (level, x, y)''s glb: api.buildings_for_tile''s features with ECEF meshes (WKB, lifted by base_height), landmark level and landmark exaggeration metadata. Example: SELECT feature_kind, lod, count(*) FROM api.export_features(0, 0, 0) GROUP BY 1, 2;';
