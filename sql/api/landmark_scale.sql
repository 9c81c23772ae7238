-- api.landmark_scale(building_id, distance_m, ramp_m) -> scale factor of a landmark seen from that distance
-- The thesis' view-dependent exaggeration: a landmark grows with the camera distance over its predefined
-- intervals (lm.building.scale_distances_m / scale_factors, filled by the landmarks stage): 1 before the first
-- distance, scale_factors[i] from scale_distances_m[i] on. ramp_m > 0 blends each step linearly over the ramp_m
-- metres before its distance, so a moving camera sees the landmark grow instead of pop (as
-- etl.landmarks.saliency.exaggeration_scale). 1 for a building that is not a landmark, NULL for an unknown id.
--   building_id  lm.building.building_id (osm.building.id of the outline)
-- Example (the top landmark seen from 5 km):
--   SELECT api.landmark_scale(building_id, 5000) FROM lm.building WHERE rank = 1;
CREATE OR REPLACE FUNCTION api.landmark_scale(
    building_id bigint,
    distance_m double precision,
    ramp_m double precision DEFAULT 0
)
RETURNS double precision
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    -- each interval adds its step (scale - previous scale), wholly past its distance, partly on its ramp
    SELECT 1 + coalesce((
        SELECT sum((q.s - q.prev) * CASE WHEN $3 > 0 THEN least(greatest(($2 - (q.b - $3)) / $3, 0), 1)
                                         ELSE ($2 >= q.b)::integer END)
        FROM (SELECT u.b, u.s, coalesce(lag(u.s) OVER (ORDER BY u.i), 1) AS prev
              FROM unnest(l.scale_distances_m, l.scale_factors) WITH ORDINALITY AS u(b, s, i)) q), 0)
    FROM lm.building l
    WHERE l.building_id = $1
$$;
COMMENT ON FUNCTION api.landmark_scale(bigint, double precision, double precision) IS
    'Scale factor of landmark building_id seen from distance_m metres (its predefined intervals in lm.building; ramp_m > 0 blends each step over that many metres); 1 for other buildings. Example: SELECT api.landmark_scale(building_id, 5000) FROM lm.building WHERE rank = 1;';
