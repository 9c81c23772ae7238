-- lod.outline_remainder(outline_id, min_area_m2) -> geometry (MultiPolygon, working CRS) or NULL
-- The part of a building outline that its building:parts do not cover, without the pieces smaller than
-- min_area_m2 (slivers where a part's edge does not quite meet the outline's); NULL when nothing is left.
-- The lod stage extrudes this instead of the whole outline when parts cover only some of it, so the outline
-- and its parts never overlap (no double volume, no outline box swallowing lower parts).
-- Example: SELECT ST_Area(lod.outline_remainder(id)) FROM osm.building WHERE n_parts > 0;
CREATE OR REPLACE FUNCTION lod.outline_remainder(outline_id bigint, min_area_m2 double precision DEFAULT 1.0)
RETURNS geometry
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT ST_Multi(ST_Collect(d.geom ORDER BY d.path))
    FROM osm.building o
    CROSS JOIN LATERAL (SELECT ST_Union(p.geom_local) AS parts FROM osm.building p WHERE p.parent_id = o.id) u
    CROSS JOIN LATERAL ST_Dump(ST_CollectionExtract(
        ST_Difference(o.geom_local, coalesce(u.parts, ST_SetSRID('GEOMETRYCOLLECTION EMPTY'::geometry,
                                                                 ST_SRID(o.geom_local)))), 3)) d
    WHERE o.id = outline_id AND ST_Area(d.geom) >= min_area_m2
$$;
COMMENT ON FUNCTION lod.outline_remainder(bigint, double precision) IS
    'Outline minus its building:parts, slivers dropped; NULL when the parts cover it. Example: SELECT ST_Area(lod.outline_remainder(id)) FROM osm.building WHERE n_parts > 0;';
