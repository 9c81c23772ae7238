-- tiles.box_visible(box, px, py, pz, planes) -> false when the oriented box lies wholly outside a frustum plane
-- planes holds the inward unit normals of the five planes of a view frustum through the camera (px, py, pz),
-- three numbers each: left, right, bottom, top and near (api.lod_for_view builds them). A box is outside a
-- plane when its centre is farther behind it than its projected radius (the separating-axis test).
-- Example: SELECT tiles.box_visible(box, 0, 0, 0, ARRAY[1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1]) FROM tiles.tile WHERE level = 0;
CREATE OR REPLACE FUNCTION tiles.box_visible(box double precision[], px double precision, py double precision,
                                             pz double precision, planes double precision[])
RETURNS boolean
LANGUAGE sql IMMUTABLE PARALLEL SAFE
AS $$
    -- written out (no FROM, no aggregate) and not STRICT, so the planner inlines it into api.lod_for_view:
    -- a STRICT function is inlined only if its body is provably strict, which greatest() and AND are not
    SELECT (planes[1] * (box[1] - px) + planes[2] * (box[2] - py) + planes[3] * (box[3] - pz)
          + abs(planes[1] * box[4] + planes[2] * box[5] + planes[3] * box[6])
          + abs(planes[1] * box[7] + planes[2] * box[8] + planes[3] * box[9])
          + abs(planes[1] * box[10] + planes[2] * box[11] + planes[3] * box[12]) >= 0)
      AND (planes[4] * (box[1] - px) + planes[5] * (box[2] - py) + planes[6] * (box[3] - pz)
          + abs(planes[4] * box[4] + planes[5] * box[5] + planes[6] * box[6])
          + abs(planes[4] * box[7] + planes[5] * box[8] + planes[6] * box[9])
          + abs(planes[4] * box[10] + planes[5] * box[11] + planes[6] * box[12]) >= 0)
      AND (planes[7] * (box[1] - px) + planes[8] * (box[2] - py) + planes[9] * (box[3] - pz)
          + abs(planes[7] * box[4] + planes[8] * box[5] + planes[9] * box[6])
          + abs(planes[7] * box[7] + planes[8] * box[8] + planes[9] * box[9])
          + abs(planes[7] * box[10] + planes[8] * box[11] + planes[9] * box[12]) >= 0)
      AND (planes[10] * (box[1] - px) + planes[11] * (box[2] - py) + planes[12] * (box[3] - pz)
          + abs(planes[10] * box[4] + planes[11] * box[5] + planes[12] * box[6])
          + abs(planes[10] * box[7] + planes[11] * box[8] + planes[12] * box[9])
          + abs(planes[10] * box[10] + planes[11] * box[11] + planes[12] * box[12]) >= 0)
      AND (planes[13] * (box[1] - px) + planes[14] * (box[2] - py) + planes[15] * (box[3] - pz)
          + abs(planes[13] * box[4] + planes[14] * box[5] + planes[15] * box[6])
          + abs(planes[13] * box[7] + planes[14] * box[8] + planes[15] * box[9])
          + abs(planes[13] * box[10] + planes[14] * box[11] + planes[15] * box[12]) >= 0)
$$;
COMMENT ON FUNCTION tiles.box_visible(double precision[], double precision, double precision, double precision, double precision[]) IS
    'True unless the tiles.tile.box lies wholly behind one of the frustum planes (inward unit normals through the camera point). Example: SELECT tiles.box_visible(box, 0, 0, 0, ARRAY[1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1]) FROM tiles.tile WHERE level = 0;';
