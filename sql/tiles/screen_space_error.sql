-- tiles.screen_space_error(geometric_error, distance, fov_rad, viewport_height) -> pixels
-- The screen-space-error rule of 3D Tiles clients, SQL's one copy of core/camera.py's screen_space_error: a
-- geometric error of e metres at distance d (m) from a camera with vertical field of view fov_rad (radians) on
-- a viewport viewport_height pixels high spans e × (H / (d × 2 tan(fov / 2))) pixels; distances below 1e-7 m
-- count as 1e-7 m. api.lod_for_view refines a tile while this exceeds max_sse; tests/db/test_camera_sql.py
-- holds it against the Python function.
-- Example: SELECT tiles.screen_space_error(10, 1000, radians(60), 1080);  -- 9.35 px
CREATE OR REPLACE FUNCTION tiles.screen_space_error(geometric_error double precision, distance double precision,
                                                    fov_rad double precision, viewport_height double precision)
RETURNS double precision
LANGUAGE sql IMMUTABLE PARALLEL SAFE
AS $$
    -- one expression, not STRICT: the planner inlines it into api.lod_for_view's walk (see tiles.box_distance)
    SELECT geometric_error * (viewport_height / (greatest(distance, 1e-7) * 2 * tan(fov_rad / 2)))
$$;
COMMENT ON FUNCTION tiles.screen_space_error(double precision, double precision, double precision, double precision) IS
    'Pixels a geometric error (m) spans at a distance (m) for a vertical field of view (radians) and viewport height (px): the 3D Tiles refinement rule, as core/camera.py. Example: SELECT tiles.screen_space_error(10, 1000, radians(60), 1080);';
