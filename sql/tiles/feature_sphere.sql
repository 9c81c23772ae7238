-- tiles.feature_sphere(geom, base_height) -> ARRAY[cx, cy, cz, radius]: a bounding sphere in ECEF metres
-- The centre of the geometry's 3D bounding box (working CRS, z in metres above the base) lifted by base_height
-- and taken to EPSG:4978; the radius half the box's diagonal, 0.2 % larger for the scale error of a
-- transverse Mercator working CRS far from its central meridian (a sphere that is too small would cull a
-- visible feature). tiles.finish_hierarchy stores it in tiles.tile_content for api.lod_for_view.
-- Example: SELECT tiles.feature_sphere(geom, 0) FROM gen.block LIMIT 1;
CREATE OR REPLACE FUNCTION tiles.feature_sphere(geom geometry, base_height double precision)
RETURNS double precision[]
LANGUAGE sql IMMUTABLE PARALLEL SAFE STRICT
AS $$
    SELECT ARRAY[ST_X(c), ST_Y(c), ST_Z(c), r]
    FROM (SELECT ST_Transform(ST_SetSRID(ST_MakePoint((ST_XMin(b) + ST_XMax(b)) / 2, (ST_YMin(b) + ST_YMax(b)) / 2,
                                                      base_height + (ST_ZMin(b) + ST_ZMax(b)) / 2),
                                         ST_SRID(geom)), 4978) AS c,
                 1.002 * sqrt((ST_XMax(b) - ST_XMin(b)) ^ 2 + (ST_YMax(b) - ST_YMin(b)) ^ 2
                              + (ST_ZMax(b) - ST_ZMin(b)) ^ 2) / 2 AS r
          FROM (SELECT Box3D(geom) AS b) s) t
$$;
COMMENT ON FUNCTION tiles.feature_sphere(geometry, double precision) IS
    'Bounding sphere ARRAY[cx, cy, cz, radius] (ECEF metres) of a working-CRS geometry whose z is metres above base_height. Example: SELECT tiles.feature_sphere(geom, 0) FROM gen.block LIMIT 1;';
