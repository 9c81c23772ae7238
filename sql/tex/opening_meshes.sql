-- tex.opening_meshes(building_ids) -> the LOD3 mesh (WKB) and semantics of the listed buildings with openings
-- The textures stage paints the LOD3 windows and doors onto the walls of LOD2 features: for the features of
-- building_ids (osm.building ids) whose LOD3 mesh has windows or doors, with the mesh's stored md5 (what
-- tex.input_digests hashes).
-- Example: SELECT building_id, length(semantics) FROM tex.opening_meshes(ARRAY(SELECT id FROM osm.building LIMIT 5));
CREATE OR REPLACE FUNCTION tex.opening_meshes(building_ids bigint[])
RETURNS TABLE (
    building_id bigint,
    semantics   bytea,
    mesh        bytea,
    mesh_md5    text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT m.building_id, m.semantics, ST_AsBinary(m.geom), m.mesh_md5 FROM lod.building_mesh m
    WHERE m.lod = 3 AND m.building_id = ANY($1) AND m.n_windows + m.n_doors > 0
    ORDER BY m.building_id
$$;
COMMENT ON FUNCTION tex.opening_meshes(bigint[]) IS
    'LOD3 mesh (WKB) and semantics of the buildings in building_ids that have windows or doors. Example: SELECT count(*) FROM tex.opening_meshes(ARRAY[1]::bigint[]);';
