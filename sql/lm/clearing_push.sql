-- lm.clearing_push(scale, landmark_radius_m, radius_m, distance_m) -> metres a building moves for a landmark
-- The displacement rule of the landmark exaggeration, one place for api.landmark_exaggeration and
-- lm.exaggeration_role (and etl.landmarks.saliency.displacement(only_growth=True) in numpy): footprints are circles;
-- a building whose circle (radius_m) lies distance_m from the centre of a landmark scaled by scale (circle
-- landmark_radius_m at scale 1) moves radially away by the overlap the scaling adds, keeping any overlap that
-- existed at scale 1. <= 0: it need not move.
-- Example: SELECT lm.clearing_push(2, 10, 5, 20); -- 5: the landmark's circle grew from 10 to 20 m
CREATE OR REPLACE FUNCTION lm.clearing_push(scale double precision, landmark_radius_m double precision,
                                            radius_m double precision, distance_m double precision)
RETURNS double precision
LANGUAGE sql IMMUTABLE PARALLEL SAFE
AS $$
    -- not STRICT (greatest() is not strict), so the planner inlines it
    SELECT scale * landmark_radius_m + radius_m - distance_m - greatest(landmark_radius_m + radius_m - distance_m, 0)
$$;
COMMENT ON FUNCTION lm.clearing_push(double precision, double precision, double precision, double precision) IS
    'Metres a building (footprint circle radius_m, distance_m from a landmark''s centre) moves away when the landmark (circle landmark_radius_m) is scaled by scale: the overlap the scaling adds; <= 0 means it stays. Example: SELECT lm.clearing_push(2, 10, 5, 20); -- 5';
