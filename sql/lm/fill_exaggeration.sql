-- lm.fill_exaggeration()
-- Replaces lm.exaggeration with lm.exaggeration_role of every building that has a role: the function, the one
-- definition of the rule, is called for the landmarks and for the buildings within a landmark's scaled radius
-- plus their own (no building it gives a row lies further). The exporter reads the table instead of
-- calling the function per feature of every tile. Run by the landmarks stage after it writes lm.building.
-- Example: CALL lm.fill_exaggeration();
CREATE OR REPLACE PROCEDURE lm.fill_exaggeration()
LANGUAGE sql
AS $$
    DELETE FROM lm.exaggeration;  -- not TRUNCATE: readers keep the rows of before until the commit
    INSERT INTO lm.exaggeration (building_id, role, landmark_id, scale_from_m, scale_step, max_scale,
                                 landmark_centroid, landmark_radius_m, gap_m, centroid)
    SELECT c.building_id, x.role, x.landmark_id, x.scale_from_m, x.scale_step, x.max_scale, x.landmark_centroid,
           x.landmark_radius_m, x.gap_m, x.centroid
    FROM (
        SELECT l.building_id FROM lm.building l WHERE l.is_landmark
        UNION
        -- a building a landmark pushes lies within its scaled radius plus the building's own (lm.clearing_push
        -- is at most scale * landmark radius + radius - distance); the GiST index takes the largest radius
        SELECT b.building_id
        FROM lm.building l
        CROSS JOIN LATERAL (SELECT l.scale_factors[cardinality(l.scale_factors)] * l.radius_m AS reach) r
        JOIN lm.building b
          ON ST_DWithin(b.centroid, l.centroid, r.reach + (SELECT max(m.radius_m) FROM lm.building m))
             AND ST_DWithin(b.centroid, l.centroid, r.reach + b.radius_m)
        WHERE l.is_landmark AND cardinality(l.scale_factors) > 0 AND NOT b.is_landmark
    ) c
    CROSS JOIN LATERAL lm.exaggeration_role(c.building_id) x
    ORDER BY c.building_id;
$$;
COMMENT ON PROCEDURE lm.fill_exaggeration() IS
    'Replaces lm.exaggeration with lm.exaggeration_role of every building that has one (landmarks and the buildings within their reach). Run by the landmarks stage. Example: CALL lm.fill_exaggeration();';
