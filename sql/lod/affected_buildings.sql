-- lod.affected_buildings(p_changed)
-- The buildings an update's lod draws again, from the buildings p_changed whose rows ingest changed (what the
-- runs since lod's last one recorded, core/changes.py): those still in osm.building, their outlines (a part's
-- change changes its outline's remainder) and every part of those outlines; and the ids of p_changed no longer
-- in osm.building (deleted), whose meshes, rejects and diagnostics go.
-- Example: SELECT * FROM lod.affected_buildings(ARRAY[4711]::bigint[]);
CREATE OR REPLACE FUNCTION lod.affected_buildings(p_changed bigint[])
RETURNS TABLE (id bigint)
LANGUAGE sql STABLE
AS $$
    WITH c AS (SELECT b.id, b.parent_id FROM osm.building b WHERE b.id = ANY(p_changed)),
         o AS (SELECT c.id FROM c UNION SELECT c.parent_id FROM c WHERE c.parent_id IS NOT NULL)
    SELECT b.id FROM osm.building b WHERE b.id IN (SELECT id FROM o) OR b.parent_id IN (SELECT id FROM o)
    UNION
    SELECT d.id FROM unnest(p_changed) d(id) WHERE NOT EXISTS (SELECT 1 FROM osm.building b WHERE b.id = d.id)
    ORDER BY 1
$$;
COMMENT ON FUNCTION lod.affected_buildings(bigint[]) IS
    'The buildings an update draws again for the changed buildings p_changed: those, their outlines and the outlines'' parts, and the ids of p_changed no longer in osm.building (deleted).';
