-- lm.flag_landmarks()
-- osm.building.protected = lm.building.is_landmark: the landmarks the landmarks stage chose are never merged
-- into blocks (gen.block_clusters) and keep their own solid in every band; every other building is
-- unprotected.
-- Example: CALL lm.flag_landmarks();
CREATE OR REPLACE PROCEDURE lm.flag_landmarks()
LANGUAGE sql
AS $$
    UPDATE osm.building SET protected = false WHERE protected;
    UPDATE osm.building b SET protected = true FROM lm.building l WHERE l.building_id = b.id AND l.is_landmark;
$$;
COMMENT ON PROCEDURE lm.flag_landmarks() IS
    'Sets osm.building.protected on the landmarks of lm.building (is_landmark) and clears it on every other building. Run by the landmarks stage.';
