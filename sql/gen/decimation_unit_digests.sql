-- gen.decimation_unit_digests(min_triangles, batch) -> per batch unit of the decimation step, its features and
-- an md5 of everything it reads
-- Every column of its gen.decimation_input rows in id order (the meshes among them): the generalize stage's
-- fingerprint of the batch (gen.unit_input) hashes this digest with its settings and code. Computed here for
-- every unit in one statement, so an update reads the meshes of the units whose fingerprint changed alone.
--   min_triangles, batch  as gen.decimation_input
-- Example: SELECT unit_level, unit_x, unit_y, cardinality(building_ids), digest FROM gen.decimation_unit_digests(64, 500);
CREATE OR REPLACE FUNCTION gen.decimation_unit_digests(min_triangles integer, batch integer)
RETURNS TABLE (
    unit_level   smallint,
    unit_x       integer,
    unit_y       integer,
    building_ids bigint[],
    digest       text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT d.unit_level, d.unit_x, d.unit_y, array_agg(d.building_id ORDER BY d.building_id),
           md5(string_agg(md5(ROW(d.*)::text), '' ORDER BY d.building_id))
    FROM gen.decimation_input($1, $2) d
    GROUP BY 1, 2, 3
    ORDER BY 1, 2, 3
$$;
COMMENT ON FUNCTION gen.decimation_unit_digests(integer, integer) IS
    'Per batch unit of the decimation step: its features (building_ids) and an md5 of every column of its gen.decimation_input rows. Example: SELECT count(*) FROM gen.decimation_unit_digests(64, 500);';
