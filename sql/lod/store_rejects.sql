-- lod.store_rejects(osm_types, osm_ids, reasons, details)
-- The buildings the lod stage could not draw (contradicting heights, failed cap triangulation), into
-- osm.reject (stage lod) with their tags and footprint, in the order given, so nothing is lost: reject i is
-- (osm_types[i], osm_ids[i]) with reasons[i] and details[i].
-- Example: CALL lod.store_rejects(ARRAY['W'], ARRAY[1]::bigint[], ARRAY['min_height_ge_height'],
--                                 ARRAY['height 3 m <= bottom 5 m']);
CREATE OR REPLACE PROCEDURE lod.store_rejects(osm_types text[], osm_ids bigint[], reasons text[], details text[])
LANGUAGE sql
AS $$
    INSERT INTO osm.reject (osm_type, osm_id, stage, reason, detail, tags, geom)
    SELECT r.osm_type, r.osm_id, 'lod', r.reason, r.detail, b.tags, b.geom
    FROM unnest(osm_types, osm_ids, reasons, details) WITH ORDINALITY r(osm_type, osm_id, reason, detail, i)
    JOIN osm.building b ON b.osm_type = r.osm_type::character(1) AND b.osm_id = r.osm_id
    ORDER BY r.i;
$$;
COMMENT ON PROCEDURE lod.store_rejects(text[], bigint[], text[], text[]) IS
    'Inserts the lod stage''s rejects (osm_types[i], osm_ids[i], reasons[i], details[i]) into osm.reject with the building''s tags and footprint. Run by the lod stage.';
