-- api.export_digest(level, x, y, single_lod DEFAULT NULL, textures DEFAULT NULL) -> (digest, n_features): a
-- fingerprint of everything api.export_features and the tile's textures give the exporter for tile (level, x, y)
-- The export compares it (with its own code and options) to the one the last published generation recorded
-- (pub.file.input_digest) and copies an unchanged tile's glb instead of building it again, so an update
-- re-exports only the tiles whose content changed. Every column of api.export_features is hashed under its own
-- name (tests/db/test_export_reuse.py checks that none is missing), geometries as their EWKB in the working CRS
-- (the mesh through the md5 of it stored with the mesh, api.feature.mesh_md5, migrations/0041)
-- (the ECEF transform and base_height are the exporter's and go into its side of the fingerprint): about half
-- the cost of api.export_features itself (Liechtenstein, every tile, one connection: 4.0 s against 7.5 s). n_features: the rows api.export_features returns.
--   level, x, y  the tile
--   single_lod   as api.export_features
--   textures     webp or ktx2: also hash api.tile_pages in that format and api.tile_uvs (NULL: untextured export),
--                through the md5 stored with each page and UV row (migrations/0042)
-- Example: SELECT * FROM api.export_digest(0, 0, 0, NULL, 'ktx2');
CREATE OR REPLACE FUNCTION api.export_digest(level integer, x integer, y integer, single_lod integer DEFAULT NULL,
                                             textures text DEFAULT NULL)
RETURNS TABLE (digest text, n_features bigint)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT md5(concat_ws('/', count(*), string_agg(md5(ROW(
               r.feature_kind, r.building_id, r.osm_type, r.osm_id, r.kind, r.building_osm_type, r.building_osm_id,
               r.name, r.building, r.height, r.min_height, r.levels, r.roof_shape, r.building_colour, r.roof_colour,
               r.building_material, r.roof_material, r.lod, r.gen_level, r.n_members, r.error_m, r.semantics,
               r.ecef_wkb, r.lm_level, r.lm_role, r.lm_landmark_osm_id, r.lm_scale_from_m, r.lm_scale_step,
               r.lm_max_scale, r.lm_radius_m, r.lm_gap_m, r.lm_centre_wkb, r.lm_own_wkb)::text), '' ORDER BY r.ord),
               (SELECT md5(string_agg(ROW(p.page_no, p.mime, p.md5)::text, '' ORDER BY p.page_no))
                FROM api.tile_pages($1, $2, $3, $5) p WHERE $5 IS NOT NULL),
               (SELECT md5(string_agg(ROW(u.feature_kind, u.feature_id, u.n_triangles, u.md5)::text,
                                      '' ORDER BY u.feature_kind, u.feature_id))
                FROM api.tile_uvs($1, $2, $3) u WHERE $5 IS NOT NULL))),
           count(*)
    FROM (
        SELECT f.ordinality AS ord, f.feature_kind, f.building_id, f.osm_type, f.osm_id, f.kind, f.building_osm_type,
               f.building_osm_id, f.name, f.building, f.height, f.min_height, f.levels, f.roof_shape,
               f.building_colour, f.roof_colour, f.building_material, f.roof_material, f.lod, f.gen_level,
               f.n_members, f.error_m, md5(f.semantics) AS semantics, f.mesh_md5 AS ecef_wkb,
               l.level AS lm_level, x.role AS lm_role, lo.osm_id AS lm_landmark_osm_id,
               x.scale_from_m AS lm_scale_from_m, x.scale_step AS lm_scale_step, x.max_scale AS lm_max_scale,
               x.landmark_radius_m AS lm_radius_m, x.gap_m AS lm_gap_m,
               md5(ST_AsEWKB(x.landmark_centroid)) AS lm_centre_wkb, md5(ST_AsEWKB(x.centroid)) AS lm_own_wkb
        FROM api.buildings_for_tile($1, $2, $3, $4) WITH ORDINALITY f
        LEFT JOIN osm.building o ON f.kind <> 'block' AND o.id = f.building_id
        LEFT JOIN lm.building l ON l.building_id = coalesce(o.parent_id, o.id)
        LEFT JOIN lm.exaggeration x ON x.building_id = l.building_id
        LEFT JOIN osm.building lo ON lo.id = x.landmark_id
    ) r
$$;
COMMENT ON FUNCTION api.export_digest(integer, integer, integer, integer, text) IS
    'Fingerprint of what the exporter reads for tile (level, x, y): every column of api.export_features (geometries as EWKB in the working CRS) and, with textures (webp or ktx2), its atlas pages and UVs; and the feature count. An export copies a tile whose fingerprint is unchanged from the last published generation. Example: SELECT * FROM api.export_digest(0, 0, 0, NULL, ''ktx2'');';
