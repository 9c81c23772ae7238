-- lod.drawn_buildings() -> bigint: buildings (an outline with its parts, or a lone part) with a LOD2 mesh
-- What the landmarks stage must score, one each (an outline drawn only by its parts counts once).
-- Example: SELECT lod.drawn_buildings();
CREATE OR REPLACE FUNCTION lod.drawn_buildings()
RETURNS bigint
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT count(DISTINCT coalesce(o.parent_id, o.id))
    FROM lod.building_mesh m JOIN osm.building o ON o.id = m.building_id
    WHERE m.lod = 2
$$;
COMMENT ON FUNCTION lod.drawn_buildings() IS
    'Buildings (outline with its parts, or a lone part) that have a LOD2 mesh: what the landmarks stage scores. Example: SELECT lod.drawn_buildings();';
