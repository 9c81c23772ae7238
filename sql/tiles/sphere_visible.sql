-- tiles.sphere_visible(cx, cy, cz, radius, px, py, pz, planes) -> false when the sphere lies wholly outside a
-- frustum plane
-- planes as for tiles.box_visible: the inward unit normals of a frustum's five planes through the camera
-- (px, py, pz), three numbers each. A sphere is outside a plane when its centre is more than its radius behind
-- it. A NULL sphere (a row from before migration 0018) counts as visible.
-- Example: SELECT tiles.sphere_visible(cx, cy, cz, radius, 0, 0, 0, ARRAY[1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1]) FROM tiles.tile_content LIMIT 1;
CREATE OR REPLACE FUNCTION tiles.sphere_visible(cx double precision, cy double precision, cz double precision,
                                                radius real, px double precision, py double precision,
                                                pz double precision, planes double precision[])
RETURNS boolean
LANGUAGE sql IMMUTABLE PARALLEL SAFE
AS $$
    -- written out and not STRICT, so the planner inlines it into api.lod_for_view (see tiles.box_visible)
    SELECT radius IS NULL
        OR (planes[1] * (cx - px) + planes[2] * (cy - py) + planes[3] * (cz - pz) >= -radius
        AND planes[4] * (cx - px) + planes[5] * (cy - py) + planes[6] * (cz - pz) >= -radius
        AND planes[7] * (cx - px) + planes[8] * (cy - py) + planes[9] * (cz - pz) >= -radius
        AND planes[10] * (cx - px) + planes[11] * (cy - py) + planes[12] * (cz - pz) >= -radius
        AND planes[13] * (cx - px) + planes[14] * (cy - py) + planes[15] * (cz - pz) >= -radius)
$$;
COMMENT ON FUNCTION tiles.sphere_visible(double precision, double precision, double precision, real, double precision, double precision, double precision, double precision[]) IS
    'True unless the sphere (ECEF centre, radius; tiles.tile_content.cx .. radius) lies wholly behind one of the frustum planes (inward unit normals through the camera point); true for a NULL radius. Example: SELECT tiles.sphere_visible(cx, cy, cz, radius, 0, 0, 0, ARRAY[1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1]) FROM tiles.tile_content LIMIT 1;';
