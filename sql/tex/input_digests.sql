-- tex.input_digests(levels, xs, ys) -> per listed tile, an md5 of everything the textures stage reads for it
-- Every column of its tex.tile_features rows in their order (the semantics bytes through their md5, the mesh
-- through the md5 stored with it, migrations/0041) and the tex.opening_meshes of its LOD2 buildings (the LOD3
-- windows and doors texturing paints onto their walls), with the feature count. The stage's fingerprint of a tile (tex.tile_input.fingerprint) hashes this
-- digest with its settings, code, band and resolution: computed here for all tiles in one statement, without
-- sending a mesh to the client, so an update sends only the units whose fingerprint changed to its workers.
--   levels, xs, ys  the tiles, as three arrays of the same length
-- Example: SELECT * FROM tex.input_digests(ARRAY[0], ARRAY[0], ARRAY[0]);
CREATE OR REPLACE FUNCTION tex.input_digests(levels integer[], xs integer[], ys integer[])
RETURNS TABLE (
    level      integer,
    x          integer,
    y          integer,
    n_features bigint,
    digest     text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT t.level, t.x, t.y, f.n, concat_ws('/', f.n, f.digest, o.digest)
    FROM unnest($1, $2, $3) AS t(level, x, y)
    CROSS JOIN LATERAL (
        SELECT count(*) AS n,
               md5(string_agg(concat_ws('/', md5(ROW(r.feature_kind, r.building_id, r.osm_type, r.osm_id, r.levels,
                                                      r.building_colour, r.roof_colour, r.building_material,
                                                      r.roof_material, r.gen_level, r.n_triangles)::text),
                                        coalesce(md5(r.semantics), '-'), coalesce(r.mesh_md5, '-')),
                              '' ORDER BY r.feature_kind, r.building_id)) AS digest,
               array_agg(r.building_id) FILTER (WHERE r.gen_level = 3 AND r.feature_kind <> 'block') AS lod2
        -- in tex.tile_features' order, by its columns: WITH ORDINALITY would keep the function from being inlined,
        -- and it would then make every mesh's WKB for nothing (0.79 s of 1.12 s over every tile of the benchmark
        -- extract)
        FROM tex.tile_features(t.level, t.x, t.y) r
    ) f
    CROSS JOIN LATERAL (
        SELECT md5(string_agg(concat_ws('/', m.building_id, coalesce(md5(m.semantics), '-'), m.mesh_md5), ''
                              ORDER BY m.building_id)) AS digest
        FROM tex.opening_meshes(f.lod2) m
    ) o
$$;
COMMENT ON FUNCTION tex.input_digests(integer[], integer[], integer[]) IS
    'Per listed tile (levels, xs, ys), an md5 of every column of its tex.tile_features rows in order and of the tex.opening_meshes of its LOD2 buildings, and its feature count: what the textures stage fingerprints. Example: SELECT * FROM tex.input_digests(ARRAY[0], ARRAY[0], ARRAY[0]);';
