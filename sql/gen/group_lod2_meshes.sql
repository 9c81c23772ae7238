-- gen.group_lod2_meshes(group_ids) -> the LOD2 mesh of every building and part of the listed buildings
-- What a level-2 footprint replaces, for measuring its error: the LOD2 meshes (WKB) of the outlines in
-- group_ids (tiles.building_tile group_id) and of their parts, with their stored md5s (what
-- gen.footprint_unit_digests hashes), in (group_id, building_id) order. Inlined into the
-- caller (LANGUAGE sql): a caller that needs the order reads building_id, not WITH ORDINALITY, which would keep
-- it from being inlined and make every mesh's WKB even where only the md5s are read.
--   group_ids  outline ids (osm.building.id)
-- Example: SELECT group_id, count(*) FROM gen.group_lod2_meshes(ARRAY(SELECT id FROM osm.building LIMIT 3))
--          GROUP BY 1;
CREATE OR REPLACE FUNCTION gen.group_lod2_meshes(group_ids bigint[])
RETURNS TABLE (
    group_id    bigint,
    building_id bigint,
    mesh        bytea,
    mesh_md5    text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT bt.group_id, bt.building_id, ST_AsBinary(m.geom), m.mesh_md5
    FROM tiles.building_tile bt JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod = 2
    WHERE bt.group_id = ANY($1)
    ORDER BY bt.group_id, bt.building_id  -- the error measure reads the meshes in order: the same, whatever
                                          -- order an update left the rows in
$$;
COMMENT ON FUNCTION gen.group_lod2_meshes(bigint[]) IS
    'LOD2 meshes (WKB, with their md5) of the buildings and parts (building_id) of the outlines group_ids, in (group_id, building_id) order. Example: SELECT count(*) FROM gen.group_lod2_meshes(ARRAY[1]::bigint[]);';
