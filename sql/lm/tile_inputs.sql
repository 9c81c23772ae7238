-- lm.tile_inputs()
-- What a tile's content reads of each building's landmark rows (api.buildings_for_tile, api.export_features):
-- its level, landmark flag, LOD2 band and exaggeration role (as an md5 of its lm.exaggeration row). The
-- landmarks stage compares these before and after its run: the buildings whose rows differ are what it changed
-- for the stages after it (core/changes.py). Score and rank are the city's, move with any edit, and no tile
-- reads them.
-- Example: SELECT * FROM lm.tile_inputs() LIMIT 5;
CREATE OR REPLACE FUNCTION lm.tile_inputs()
RETURNS TABLE (building_id bigint, level smallint, is_landmark boolean, lod2_band smallint, exaggeration text)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT l.building_id, l.level, l.is_landmark, l.lod2_band, md5(x::text)
    FROM lm.building l LEFT JOIN lm.exaggeration x USING (building_id)
$$;
COMMENT ON FUNCTION lm.tile_inputs() IS
    'Per building, what a tile''s content reads of its landmark rows (level, landmark flag, LOD2 band, an md5 of its exaggeration role): compared before and after the landmarks stage to find what it changed.';
