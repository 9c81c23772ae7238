-- tiles.feature_sphere(box, srid, base_height) -> ARRAY[cx, cy, cz, radius]: a bounding sphere in ECEF metres
-- The centre of a feature's 3D bounding box (Box3D of its geometry: working CRS srid, z in metres above the
-- base) lifted by base_height and taken to EPSG:4978; the radius half the box's diagonal, 0.2 % larger for the
-- scale error of a transverse Mercator working CRS far from its central meridian (a sphere that is too small
-- would cull a visible feature). tiles.finish_hierarchy stores it in tiles.tile_content for api.lod_for_view.
-- It takes the box, not the geometry, and is one expression, so the planner inlines it into the caller's query:
-- called as a function per feature it cost 5 s of the 7 s of Liechtenstein's hierarchy step (a mesh detoasted
-- for every call); the caller computes Box3D once per feature, and the centre is transformed three times (a
-- microsecond each).
-- Example: SELECT tiles.feature_sphere(Box3D(geom), ST_SRID(geom), 0) FROM gen.block LIMIT 1;
CREATE OR REPLACE FUNCTION tiles.feature_sphere(box box3d, srid integer, base_height double precision)
RETURNS double precision[]
LANGUAGE sql IMMUTABLE PARALLEL SAFE
AS $$
    SELECT CASE WHEN $1 IS NOT NULL THEN ARRAY[
        ST_X(ST_Transform(ST_SetSRID(ST_MakePoint((ST_XMin($1) + ST_XMax($1)) / 2, (ST_YMin($1) + ST_YMax($1)) / 2,
                                                  $3 + (ST_ZMin($1) + ST_ZMax($1)) / 2), $2), 4978)),
        ST_Y(ST_Transform(ST_SetSRID(ST_MakePoint((ST_XMin($1) + ST_XMax($1)) / 2, (ST_YMin($1) + ST_YMax($1)) / 2,
                                                  $3 + (ST_ZMin($1) + ST_ZMax($1)) / 2), $2), 4978)),
        ST_Z(ST_Transform(ST_SetSRID(ST_MakePoint((ST_XMin($1) + ST_XMax($1)) / 2, (ST_YMin($1) + ST_YMax($1)) / 2,
                                                  $3 + (ST_ZMin($1) + ST_ZMax($1)) / 2), $2), 4978)),
        1.002 * sqrt((ST_XMax($1) - ST_XMin($1)) ^ 2 + (ST_YMax($1) - ST_YMin($1)) ^ 2
                     + (ST_ZMax($1) - ST_ZMin($1)) ^ 2) / 2] END
$$;
COMMENT ON FUNCTION tiles.feature_sphere(box3d, integer, double precision) IS
    'Bounding sphere ARRAY[cx, cy, cz, radius] (ECEF metres) of a feature from its Box3D in working CRS srid, z metres above base_height. Example: SELECT tiles.feature_sphere(Box3D(geom), ST_SRID(geom), 0) FROM gen.block LIMIT 1;';
