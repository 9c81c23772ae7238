-- api.landmark_exaggeration(camera, ramp_m) -> every landmark's scale for a camera, and who must move
-- The thesis' landmark enhancement for one camera position: each landmark (lm.building.is_landmark) with its
-- distance from the camera and its scale factor (api.landmark_scale), and every other building the scaled
-- landmarks would overlap with the offset that clears it. Footprints are circles (lm.building.centroid,
-- radius_m); a building is pushed radially away from the landmark centre by the overlap the scaling adds
-- (an overlap that already existed at scale 1, between adjacent buildings, is kept, so neighbours move
-- continuously from 0 as the landmark grows); pushed by several landmarks, it takes the largest push. Landmarks
-- stay where they are. lm.clearing_push is the rule (etl.landmarks.saliency.displacement(combine="max",
-- only_growth=True) in numpy).
--   camera  point with Z: longitude, latitude (any SRID PostGIS can take to EPSG:4326) and height above the
--           ellipsoid (m), as api.lod_for_view; ground is the bottom of the root tile's region (0 before tiles)
--   ramp_m  as api.landmark_scale
-- Rows: role 'landmark' (dx = dy = 0) or 'displaced' (landmark_id the landmark that pushes it, distance_m and
-- scale that landmark's); dx, dy metres along the working CRS's x (east) and y (north) axes.
-- Example (Helsinki, 3 km up over the centre):
--   SELECT role, count(*), max(scale), max(sqrt(dx ^ 2 + dy ^ 2))
--   FROM api.landmark_exaggeration(ST_SetSRID(ST_MakePoint(24.94, 60.17, 3000), 4326)) GROUP BY role;
CREATE OR REPLACE FUNCTION api.landmark_exaggeration(camera geometry, ramp_m double precision DEFAULT 0)
RETURNS TABLE (
    role        text,
    building_id bigint,
    osm_type    text,
    osm_id      bigint,
    landmark_id bigint,
    distance_m  double precision,
    scale       double precision,
    dx          double precision,
    dy          double precision
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    WITH cam AS MATERIALIZED (
        SELECT ST_Transform(ST_Force2D(c.g), meta.working_srid()) AS p,
               ST_Z(c.g) - coalesce((SELECT t.region[5] FROM tiles.tile t WHERE t.level = 0), 0) AS z
        FROM (SELECT ST_Transform(ST_Force3D($1), 4326) AS g) c
    ), lmk AS MATERIALIZED (
        -- distance to the middle of the landmark's height
        SELECT l.building_id, l.centroid, l.radius_m, d.m AS distance_m,
               api.landmark_scale(l.building_id, d.m, $2) AS scale
        FROM lm.building l CROSS JOIN cam
        CROSS JOIN LATERAL (SELECT sqrt(ST_Distance(l.centroid, cam.p) ^ 2 + (cam.z - l.height_m / 2) ^ 2) AS m) d
        WHERE l.is_landmark
    ), push AS (
        SELECT DISTINCT ON (o.building_id) o.building_id, k.building_id AS landmark_id, v.push, v.dist,
               ST_X(o.centroid) - ST_X(k.centroid) AS ex, ST_Y(o.centroid) - ST_Y(k.centroid) AS ey
        FROM lmk k
        CROSS JOIN (SELECT max(radius_m) AS r FROM lm.building) reach
        JOIN lm.building o ON NOT o.is_landmark
                          AND ST_DWithin(o.centroid, k.centroid, k.scale * k.radius_m + reach.r)
        CROSS JOIN LATERAL (SELECT ST_Distance(o.centroid, k.centroid) AS dist) dd
        CROSS JOIN LATERAL (
            SELECT dd.dist, lm.clearing_push(k.scale, k.radius_m, o.radius_m, dd.dist) AS push) v
        WHERE k.scale > 1 AND v.push > 0
        ORDER BY o.building_id, v.push DESC
    )
    SELECT 'landmark', k.building_id, b.osm_type::text, b.osm_id, k.building_id, k.distance_m, k.scale, 0, 0
    FROM lmk k JOIN osm.building b ON b.id = k.building_id
    UNION ALL
    -- a building on the landmark's centre goes east
    SELECT 'displaced', p.building_id, b.osm_type::text, b.osm_id, p.landmark_id, k.distance_m, k.scale,
           CASE WHEN p.dist > 0 THEN p.ex / p.dist * p.push ELSE p.push END,
           CASE WHEN p.dist > 0 THEN p.ey / p.dist * p.push ELSE 0 END
    FROM push p JOIN lmk k ON k.building_id = p.landmark_id JOIN osm.building b ON b.id = p.building_id
$$;
COMMENT ON FUNCTION api.landmark_exaggeration(geometry, double precision) IS
    'For a camera (lon, lat, ellipsoidal height): every landmark with its distance and scale factor (api.landmark_scale), and every other building its scaled footprint circle would newly overlap with the offset (dx, dy in metres, working CRS) that clears it. Example: SELECT role, count(*), max(scale) FROM api.landmark_exaggeration(ST_SetSRID(ST_MakePoint(24.94, 60.17, 3000), 4326)) GROUP BY role;';
