-- tiles.box_distance(box, px, py, pz) -> metres from point (px, py, pz) to an oriented box (0 inside)
-- box is tiles.tile.box: centre (3) then three half-axis vectors (3 × 3), all ECEF metres; the distance is
-- measured as CesiumJS measures it for a box bounding volume (OrientedBoundingBox.distanceSquaredTo).
-- Example: SELECT tiles.box_distance(box, 0, 0, 0) FROM tiles.tile WHERE level = 0;
CREATE OR REPLACE FUNCTION tiles.box_distance(box double precision[], px double precision, py double precision,
                                              pz double precision)
RETURNS double precision
LANGUAGE sql IMMUTABLE PARALLEL SAFE
AS $$
    -- written out (no FROM, no aggregate) and not STRICT, so the planner inlines it into api.lod_for_view:
    -- a STRICT function is inlined only if its body is provably strict, which greatest() and AND are not
    SELECT sqrt(
        greatest(abs(((px - box[1]) * box[4] + (py - box[2]) * box[5] + (pz - box[3]) * box[6])) / greatest(sqrt(box[4] ^ 2 + box[5] ^ 2 + box[6] ^ 2), 1e-9) - greatest(sqrt(box[4] ^ 2 + box[5] ^ 2 + box[6] ^ 2), 1e-9), 0) ^ 2
      + greatest(abs(((px - box[1]) * box[7] + (py - box[2]) * box[8] + (pz - box[3]) * box[9])) / greatest(sqrt(box[7] ^ 2 + box[8] ^ 2 + box[9] ^ 2), 1e-9) - greatest(sqrt(box[7] ^ 2 + box[8] ^ 2 + box[9] ^ 2), 1e-9), 0) ^ 2
      + greatest(abs(((px - box[1]) * box[10] + (py - box[2]) * box[11] + (pz - box[3]) * box[12])) / greatest(sqrt(box[10] ^ 2 + box[11] ^ 2 + box[12] ^ 2), 1e-9) - greatest(sqrt(box[10] ^ 2 + box[11] ^ 2 + box[12] ^ 2), 1e-9), 0) ^ 2)
$$;
COMMENT ON FUNCTION tiles.box_distance(double precision[], double precision, double precision, double precision) IS
    'Distance (m) from an ECEF point to a tiles.tile.box (0 inside). Example: SELECT tiles.box_distance(box, 4e6, 7e5, 5e6) FROM tiles.tile WHERE level = 0;';
