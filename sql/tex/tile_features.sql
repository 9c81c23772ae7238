-- tex.tile_features(level, x, y) -> the features of tile (level, x, y) the textures stage textures
-- api.buildings_for_tile's rows with what texturing needs: the tags that choose the textures, the band, the
-- mesh (WKB, in the triangle order the exporter writes, so UVs per triangle corner line up) and its
-- per-triangle semantics, and the mesh's stored md5 (what tex.input_digests hashes); ordered by (feature_kind,
-- building_id).
-- Example: SELECT feature_kind, count(*), sum(n_triangles) FROM tex.tile_features(0, 0, 0) GROUP BY 1;
CREATE OR REPLACE FUNCTION tex.tile_features(level integer, x integer, y integer)
RETURNS TABLE (
    feature_kind      text,
    building_id       bigint,
    osm_type          text,
    osm_id            bigint,
    levels            real,
    building_colour   text,
    roof_colour       text,
    building_material text,
    roof_material     text,
    gen_level         smallint,
    n_triangles       integer,
    semantics         bytea,
    mesh              bytea,
    mesh_md5          text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT f.feature_kind, f.building_id, f.osm_type, f.osm_id, f.levels, f.building_colour, f.roof_colour,
           f.building_material, f.roof_material, f.gen_level, f.n_triangles, f.semantics, ST_AsBinary(f.geom),
           f.mesh_md5
    FROM api.buildings_for_tile($1, $2, $3) f
    ORDER BY f.feature_kind, f.building_id
$$;
COMMENT ON FUNCTION tex.tile_features(integer, integer, integer) IS
    'Features of tile (level, x, y) as api.buildings_for_tile gives them, with texture tags, band, mesh (WKB) and semantics; (feature_kind, building_id) order. Example: SELECT count(*) FROM tex.tile_features(0, 0, 0);';
