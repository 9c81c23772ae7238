-- 0017: what a landmark's view-dependent exaggeration needs: its footprint circle and its predefined intervals.
ALTER TABLE lm.building
    ADD COLUMN radius_m real NOT NULL DEFAULT 0,
    ADD COLUMN scale_distances_m real[],
    ADD COLUMN scale_factors real[],
    ADD CONSTRAINT building_scale_intervals_check CHECK (
        cardinality(scale_distances_m) IS NOT DISTINCT FROM cardinality(scale_factors)
        AND (scale_distances_m IS NULL OR is_landmark));
COMMENT ON COLUMN lm.building.radius_m IS 'Radius (m) of the circle around centroid that covers the outline: the footprint circle with which api.landmark_exaggeration displaces neighbours.';
COMMENT ON COLUMN lm.building.scale_distances_m IS 'Landmarks: camera distances (m) where the next exaggeration interval starts (increasing); NULL for other buildings. The first is where the landmark would fill fewer than lm_min_screen_px pixels of a 1080 px, 60° view, each next one lm_scale_step times further.';
COMMENT ON COLUMN lm.building.scale_factors IS 'Landmarks: the scale factor from the matching scale_distances_m on (1 before the first), lm_scale_step per interval up to the landmark''s top scale (lm_max_scale at the top of the hierarchy).';
