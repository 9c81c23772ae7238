-- api.lod_for_view(camera, heading, pitch, fov, viewport_height, max_sse, aspect, cull_features)
--   -> what a client draws
-- For a perspective camera, every building, part or block in the view frustum a 3D Tiles client draws, at
-- which LOD, from which tile and with which screen-space error. It walks tiles.tile as a client walks
-- tileset.json with REPLACE refinement: starting at the root, a tile in the view frustum is refined into its
-- children while its screen-space error (tiles.screen_space_error: geometric_error × viewport_height /
-- (distance × 2 tan(fov / 2))) exceeds max_sse;
-- distance is measured to the tile's box (tiles.box_distance), culling uses the five frustum planes
-- (tiles.box_visible). The features of the tiles it stops at are read from tiles.tile_content, the list of
-- api.buildings_for_tile's rows the generalize stage stored, so the exporter and this function agree by
-- construction and a view costs one index scan per tile, no meshes. Of a drawn tile only the features whose
-- bounding sphere meets the frustum are returned (tiles.sphere_visible on tiles.tile_content's spheres): a
-- coarse tile kilometres wide is mostly outside the view of a low camera, and its hidden features are half of
-- what such a view would return. cull_features => false returns every feature of every drawn tile, what a
-- client loads.
--   camera           point with Z: longitude, latitude (any SRID PostGIS can take to EPSG:4326) and height
--                    above the WGS84 ellipsoid (m), as CesiumJS's camera.positionCartographic
--   heading, pitch   degrees: heading clockwise from north, pitch up from the horizon (-90 looks straight
--                    down), as camera.heading / camera.pitch; no roll
--   fov              vertical field of view (degrees); aspect = viewport width / height
--   viewport_height  pixels (drawing buffer height); max_sse: pixels (CesiumJS maximumScreenSpaceError)
--   cull_features    false: every feature of the drawn tiles, in the frustum or not
-- lod is 0 for a block, 1 for a simplified solid, 2 roofs, 3 facades; gen_level below 0 marks the coarser
-- blocks of a large city's upper tiles.
-- Example (Helsinki, 1.5 km up, looking north and down):
--   SELECT lod, count(*), round(max(screen_space_error)::numeric, 1)
--   FROM api.lod_for_view(ST_SetSRID(ST_MakePoint(24.94, 60.16, 1500), 4326), 0, -45, 60, 1080) GROUP BY lod;
CREATE OR REPLACE FUNCTION api.lod_for_view(
    camera geometry,
    heading double precision,
    pitch double precision,
    fov double precision DEFAULT 60,
    viewport_height integer DEFAULT 1080,
    max_sse double precision DEFAULT 16,
    aspect double precision DEFAULT 16.0 / 9.0,
    cull_features boolean DEFAULT true
)
RETURNS TABLE (
    feature_kind       text,
    feature_id         bigint,
    osm_type           text,
    osm_id             bigint,
    lod                smallint,
    gen_level          smallint,
    n_members          integer,
    level              smallint,
    x                  integer,
    y                  integer,
    distance_m         double precision,
    screen_space_error double precision
)
LANGUAGE plpgsql STABLE PARALLEL SAFE
-- one generic plan: the walk's shape does not depend on the camera, and a custom plan per call costs more
-- than the walk
SET plan_cache_mode = force_generic_plan
AS $$
#variable_conflict use_column
BEGIN
    -- plpgsql, not sql: PostgreSQL plans a SQL function's body on every call (35 ms here, 7x the execution
    -- at 1M buildings); plpgsql keeps a generic plan for the session
    RETURN QUERY
    -- geo and cam are MATERIALIZED: inlined, every use of lam, phi, ... would repeat ST_Transform (~2 ms)
    WITH RECURSIVE geo AS MATERIALIZED (
        SELECT radians(ST_X(g)) AS lam, radians(ST_Y(g)) AS phi, ST_Z(g) AS h,
               radians($2) AS hd, radians($3) AS pt, radians($4) / 2 AS tv
        FROM (SELECT ST_Transform(ST_Force3D($1), 4326) AS g) s
    ), frame AS (
        -- WGS84: position and east/north/up axes in ECEF; view direction, right and up vectors
        SELECT (n + h) * cos(phi) * cos(lam) AS px, (n + h) * cos(phi) * sin(lam) AS py,
               (n * (1 - 0.0066943799901413165) + h) * sin(phi) AS pz,
               ARRAY[-sin(lam), cos(lam), 0] AS e,
               ARRAY[-sin(phi) * cos(lam), -sin(phi) * sin(lam), cos(phi)] AS nn,
               ARRAY[cos(phi) * cos(lam), cos(phi) * sin(lam), sin(phi)] AS u,
               hd, pt, tv, atan($7 * tan(tv)) AS th
        FROM geo CROSS JOIN LATERAL (SELECT 6378137.0 / sqrt(1 - 0.0066943799901413165 * sin(phi) ^ 2) AS n) r
    ), dirs AS (
        SELECT px, py, pz, tv, th,
               ARRAY[cos(pt) * sin(hd) * e[1] + cos(pt) * cos(hd) * nn[1] + sin(pt) * u[1],
                     cos(pt) * sin(hd) * e[2] + cos(pt) * cos(hd) * nn[2] + sin(pt) * u[2],
                     cos(pt) * sin(hd) * e[3] + cos(pt) * cos(hd) * nn[3] + sin(pt) * u[3]] AS d,
               ARRAY[cos(hd) * e[1] - sin(hd) * nn[1], cos(hd) * e[2] - sin(hd) * nn[2],
                     cos(hd) * e[3] - sin(hd) * nn[3]] AS r
        FROM frame
    ), cam AS MATERIALIZED (
        SELECT px, py, pz, tv, v.up, ARRAY[
            cos(th) * r[1] + sin(th) * d[1], cos(th) * r[2] + sin(th) * d[2], cos(th) * r[3] + sin(th) * d[3],
            -cos(th) * r[1] + sin(th) * d[1], -cos(th) * r[2] + sin(th) * d[2], -cos(th) * r[3] + sin(th) * d[3],
            cos(tv) * v.up[1] + sin(tv) * d[1], cos(tv) * v.up[2] + sin(tv) * d[2], cos(tv) * v.up[3] + sin(tv) * d[3],
            -cos(tv) * v.up[1] + sin(tv) * d[1], -cos(tv) * v.up[2] + sin(tv) * d[2], -cos(tv) * v.up[3] + sin(tv) * d[3],
            d[1], d[2], d[3]] AS planes
        FROM dirs
        CROSS JOIN LATERAL (SELECT ARRAY[r[2] * d[3] - r[3] * d[2], r[3] * d[1] - r[1] * d[3],
                                         r[1] * d[2] - r[2] * d[1]] AS up) v
    ), walk AS (
        SELECT t.level, t.x, t.y, t.is_leaf, dist.m AS distance_m,
               tiles.screen_space_error(t.geometric_error, dist.m, 2 * cam.tv, $5) AS sse
        FROM cam JOIN tiles.tile t ON t.level = 0 AND t.x = 0 AND t.y = 0
        CROSS JOIN LATERAL (SELECT tiles.box_distance(t.box, cam.px, cam.py, cam.pz) AS m) dist
        WHERE tiles.box_visible(t.box, cam.px, cam.py, cam.pz, cam.planes)
        UNION ALL
        SELECT c.level, c.x, c.y, c.is_leaf, dist.m,
               tiles.screen_space_error(c.geometric_error, dist.m, 2 * cam.tv, $5)
        FROM walk w
        CROSS JOIN cam
        JOIN tiles.tile c ON c.level = w.level + 1 AND c.x BETWEEN 2 * w.x AND 2 * w.x + 1
                         AND c.y BETWEEN 2 * w.y AND 2 * w.y + 1
        CROSS JOIN LATERAL (SELECT tiles.box_distance(c.box, cam.px, cam.py, cam.pz) AS m) dist
        WHERE NOT w.is_leaf AND w.sse > $6
          AND tiles.box_visible(c.box, cam.px, cam.py, cam.pz, cam.planes)
    )
    SELECT f.feature_kind, f.feature_id, f.osm_type, f.osm_id, f.lod, f.gen_level, f.n_members,
           w.level, w.x, w.y, w.distance_m, w.sse
    FROM walk w
    CROSS JOIN cam
    JOIN tiles.tile_content f ON f.level = w.level AND f.x = w.x AND f.y = w.y
    WHERE (w.is_leaf OR w.sse <= $6)
      AND (NOT $8 OR tiles.sphere_visible(f.cx, f.cy, f.cz, f.radius, cam.px, cam.py, cam.pz, cam.planes));
END
$$;
COMMENT ON FUNCTION api.lod_for_view(geometry, double precision, double precision, double precision, integer, double precision, double precision, boolean) IS
    'Every feature in the view frustum a 3D Tiles client draws for a perspective camera (REPLACE refinement over tiles.tile, the same tiles and content as the exported tileset; cull_features => false: every feature of the drawn tiles): LOD (0 block .. 3 facades), tile, distance and screen-space error. Example: SELECT lod, count(*) FROM api.lod_for_view(ST_SetSRID(ST_MakePoint(24.94, 60.16, 1500), 4326), 0, -45, 60, 1080) GROUP BY lod;';
