-- gen.footprint_unit_digests(pin_m, batch) -> per batch unit of the footprint step, its buildings and an md5 of
-- everything it reads
-- Every column of its gen.footprint_input rows in id order but the neighbours' boundaries (pinned), what pins them
-- instead: the id and outline of every outline (parent_id NULL) within pin_m of the unit's extent, a superset of
-- every building's neighbours within pin_m (looked up once per unit, not once per building: that lookup was about
-- two thirds of this function's time over the benchmark extract), and the LOD2 meshes its errors are measured
-- against (gen.group_lod2_meshes, in their order, through the md5 stored with each, migrations/0041): the
-- generalize stage's fingerprint of the batch (gen.unit_input) hashes this digest with its settings and code.
-- Computed here for every unit in one statement, so an update reads the rows and meshes of the units whose
-- fingerprint changed alone, instead of every building's.
--   pin_m, batch  as gen.footprint_input
-- Example: SELECT unit_level, unit_x, unit_y, cardinality(group_ids), digest FROM gen.footprint_unit_digests(0.05, 500);
CREATE OR REPLACE FUNCTION gen.footprint_unit_digests(pin_m double precision, batch integer)
RETURNS TABLE (
    unit_level smallint,
    unit_x     integer,
    unit_y     integer,
    group_ids  bigint[],
    digest     text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT u.unit_level, u.unit_x, u.unit_y, u.ids, concat_ws('/', u.digest, p.digest, m.digest)
    FROM (
        SELECT f.unit_level, f.unit_x, f.unit_y, array_agg(f.group_id ORDER BY f.group_id) AS ids,
               md5(string_agg(md5(ROW(f.*)::text), '' ORDER BY f.group_id)) AS digest
        FROM gen.footprint_input($1, $2, NULL, false) f
        GROUP BY 1, 2, 3
    ) u
    CROSS JOIN LATERAL (
        -- the outlines that may pin the unit's: footprint_input's neighbours of each of its buildings (an outline
        -- whose box meets the building's expanded by pin_m) all meet the unit's extent expanded by pin_m
        SELECT md5(string_agg(concat_ws('/', n.id, md5(ST_AsEWKB(n.geom_local))), '' ORDER BY n.id)) AS digest
        FROM (SELECT ST_SetSRID(ST_Expand(ST_Extent(o.geom_local), $1)::geometry, min(ST_SRID(o.geom_local))) AS box
              FROM osm.building o WHERE o.id = ANY(u.ids)) e
        JOIN osm.building n ON n.geom_local && e.box AND n.parent_id IS NULL
    ) p
    CROSS JOIN LATERAL (
        -- in the function's order, by its columns (WITH ORDINALITY would keep it from being inlined: it would then
        -- make the WKB of every LOD2 mesh of the city for nothing)
        SELECT md5(string_agg(concat_ws('/', g.group_id, g.mesh_md5), '' ORDER BY g.group_id, g.building_id)) AS digest
        FROM gen.group_lod2_meshes(u.ids) g
    ) m
    ORDER BY 1, 2, 3
$$;
COMMENT ON FUNCTION gen.footprint_unit_digests(double precision, integer) IS
    'Per batch unit of the footprint step: its buildings (group_ids) and an md5 of every column of its gen.footprint_input rows but pinned, of every outline within pin_m of the unit (what pins them) and of their LOD2 meshes (gen.group_lod2_meshes). Example: SELECT count(*) FROM gen.footprint_unit_digests(0.05, 500);';
