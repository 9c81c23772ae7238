-- lod.straight_skeleton(geom) -> MULTILINESTRING of the straight skeleton's arcs, or NULL when SFCGAL fails
-- The LOD2 roofs of hipped, gabled and related shapes are read off these arcs (etl/lod/roofs.py). SFCGAL
-- raises on some degenerate footprints; one such building must not abort the stage, so the error becomes
-- NULL (the stage then draws the roof flat and records why).
-- Example:
--   SELECT ST_AsText(lod.straight_skeleton('POLYGON((0 0,20 0,20 10,0 10,0 0))'));
CREATE OR REPLACE FUNCTION lod.straight_skeleton(footprint geometry)
RETURNS geometry
-- not PARALLEL SAFE: the EXCEPTION block opens a subtransaction, which parallel workers cannot
LANGUAGE plpgsql IMMUTABLE STRICT PARALLEL UNSAFE
AS $$
BEGIN
    RETURN ST_StraightSkeleton(footprint);
EXCEPTION WHEN OTHERS THEN
    RETURN NULL;
END
$$;
COMMENT ON FUNCTION lod.straight_skeleton(geometry) IS
    'SFCGAL ST_StraightSkeleton, NULL instead of an error. Example: SELECT ST_AsText(lod.straight_skeleton(geom_local)) FROM osm.building LIMIT 1;';
