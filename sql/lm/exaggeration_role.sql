-- lm.exaggeration_role(building_id) -> how a building takes part in the landmarks' exaggeration
-- What the exporter writes into each feature's metadata so a client can exaggerate without asking the
-- database (api.landmark_exaggeration answers for one camera): for a landmark, itself (role 1); for another
-- building, the landmark that would push it furthest at that landmark's top scale (role 2; the rule of
-- api.landmark_exaggeration); no row for the rest. With the landmark's intervals (first distance, step, top
-- scale: distances from_m × step^i, scales min(step^(i+1), top)), its footprint circle and the building's
-- gap to it at scale 1 (centre distance minus both radii; negative when the circles already overlap).
--   building_id  lm.building.building_id (osm.building.id of the outline)
-- Example: SELECT * FROM lm.exaggeration_role((SELECT building_id FROM lm.building WHERE rank = 1));
CREATE OR REPLACE FUNCTION lm.exaggeration_role(building_id bigint)
RETURNS TABLE (
    role              smallint,
    landmark_id       bigint,
    scale_from_m      real,
    scale_step        real,
    max_scale         real,
    landmark_centroid geometry,
    landmark_radius_m real,
    gap_m             double precision,
    centroid          geometry
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT CASE WHEN b.is_landmark THEN 1 ELSE 2 END::smallint, k.building_id, k.scale_distances_m[1],
           k.scale_factors[1], k.top, k.centroid, k.radius_m,
           CASE WHEN b.is_landmark THEN 0 ELSE k.dist - k.radius_m - b.radius_m END, b.centroid
    FROM lm.building b
    CROSS JOIN LATERAL (
        SELECT l.building_id, l.scale_distances_m, l.scale_factors, l.centroid, l.radius_m, t.top, d.dist,
               lm.clearing_push(t.top, l.radius_m, b.radius_m, d.dist) AS push
        FROM lm.building l
        CROSS JOIN LATERAL (SELECT l.scale_factors[cardinality(l.scale_factors)] AS top) t
        CROSS JOIN LATERAL (SELECT ST_Distance(b.centroid, l.centroid) AS dist) d
        WHERE l.is_landmark AND cardinality(l.scale_factors) > 0
          AND (l.building_id = b.building_id
               OR (NOT b.is_landmark
                   -- a constant reach, so the GiST index on centroid serves
                   AND ST_DWithin(l.centroid, b.centroid,
                                  (SELECT max(m.scale_factors[cardinality(m.scale_factors)] * m.radius_m)
                                   FROM lm.building m WHERE m.is_landmark) + b.radius_m)))
        ORDER BY l.building_id = b.building_id DESC, 8 DESC, l.building_id  -- ties: the lowest id, always
        LIMIT 1
    ) k
    WHERE b.building_id = $1 AND (b.is_landmark OR k.push > 0)
$$;
COMMENT ON FUNCTION lm.exaggeration_role(bigint) IS
    'How building_id takes part in landmark exaggeration: role 1 a landmark, role 2 a building the landmark_id''s footprint circle would cover at its top scale; the landmark''s intervals (scale_from_m, scale_step, max_scale), circle and the gap at scale 1. No row for other buildings. Example: SELECT * FROM lm.exaggeration_role((SELECT building_id FROM lm.building WHERE rank = 1));';
