-- gen.footprint_input(pin_m, batch, ids DEFAULT NULL, pins DEFAULT true) -> one row per building (an outline with
-- its parts), by batch unit, then id
-- What the generalize stage simplifies at level 2: every building of the tile quadtree (tiles.building_tile
-- group_id) with its outline, the area-weighted height of its LOD2 meshes (the tallest one's where they have
-- no area), the lowest bottom, its LOD2 triangles, whether LOD3 put openings on it, and the boundaries of
-- the outlines within pin_m of it (their shared walls stay where they are), and the unit of the batches it goes
-- into (gen.batch_units: the rows of one unit are one batch).
--   pin_m  distance (m) within which a neighbour's boundary pins vertices (etl.generalize.simplify.PIN_DISTANCE)
--   batch  settings.gen_batch_features (gen.batch_units)
--   ids    only these buildings (group ids; NULL: all): an update reads only the batches it computes again,
--          without aggregating every building's meshes first
--   pins   false: pinned is NULL, the neighbours not looked up (gen.footprint_unit_digests hashes what pins a
--          batch's outlines per batch, not per building: most of this function's time over the city)
-- Streamed by a server-side cursor: LANGUAGE sql, STABLE and not STRICT, so the planner inlines it into the
-- caller's query and it plans as that query would; a non-inlined set-returning function would be
-- materialized whole before its first row.
-- Example: SELECT group_id, top, bottom, n_triangles_in, openings FROM gen.footprint_input(0.1, 2000) LIMIT 5;
CREATE OR REPLACE FUNCTION gen.footprint_input(pin_m double precision, batch integer, ids bigint[] DEFAULT NULL,
                                                pins boolean DEFAULT true)
RETURNS TABLE (
    group_id       bigint,
    footprint      bytea,
    top            double precision,
    bottom         real,
    n_triangles_in bigint,
    openings       boolean,
    pinned         bytea,
    unit_level     smallint,
    unit_x         integer,
    unit_y         integer
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT o.id, ST_AsBinary(o.geom_local), coalesce(s.height, s.hmax), s.min_height, s.n_in, s.openings,
           ST_AsBinary(nb.fixed), u.unit_level, u.unit_x, u.unit_y
    FROM (
        SELECT bt.group_id, bt.level, bt.x, bt.y,  -- one leaf per building: its outline's centre placed it
               -- float sums in member order: the same bits whatever order an update left the rows in
               sum(m.height * m.ground_area_m2 ORDER BY m.building_id) FILTER (WHERE m.lod = 2)
                   / nullif(sum(m.ground_area_m2 ORDER BY m.building_id) FILTER (WHERE m.lod = 2), 0) AS height,
               max(m.height) AS hmax, min(m.min_height) AS min_height,
               sum(m.n_triangles) FILTER (WHERE m.lod = 2) AS n_in,
               bool_or(m.n_windows + m.n_doors > 0) FILTER (WHERE m.lod = 3) AS openings
        FROM tiles.building_tile bt
        JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod IN (2, 3)
        WHERE $3 IS NULL OR bt.group_id = ANY($3)
        GROUP BY bt.group_id, bt.level, bt.x, bt.y
    ) s
    JOIN osm.building o ON o.id = s.group_id
    JOIN gen.batch_units($2) u ON (u.level, u.x, u.y) = (s.level, s.x, s.y)
    LEFT JOIN LATERAL (
        -- in id order: the same bytes whatever order an update left the rows and the index in
        SELECT ST_Collect(ST_Boundary(n.geom_local) ORDER BY n.id) AS fixed
        FROM osm.building n
        WHERE $4 AND n.geom_local && ST_Expand(o.geom_local, $1) AND n.id <> o.id AND n.parent_id IS NULL
          AND ST_DWithin(n.geom_local, o.geom_local, $1)
    ) nb ON true
    ORDER BY u.unit_level, u.unit_x, u.unit_y, o.id
$$;
COMMENT ON FUNCTION gen.footprint_input(double precision, integer, bigint[], boolean) IS
    'Buildings (outline + parts) for the level-2 footprints: outline (WKB), area-weighted LOD2 height, bottom, LOD2 triangles, LOD3 openings, neighbours'' boundaries within pin_m (WKB; NULL unless pins), batch unit (gen.batch_units); by unit, then id; only the buildings ids if given. Example: SELECT * FROM gen.footprint_input(0.1, 2000) LIMIT 5;';
