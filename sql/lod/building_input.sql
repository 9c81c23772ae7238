-- lod.building_input(coverage, skeleton_shapes, ids) -> one row per building or part the lod stage draws, in id order
-- Every osm.building row except outlines whose parts cover at least `coverage` of them (the S3DB outline
-- rule: their parts are drawn instead, lod.diagnose_hidden_outlines), with its height tags, its footprint
-- (WKB; for an outline with parts what they leave uncovered, lod.outline_remainder, NULL when that is only
-- slivers) and, for roof shapes that need it, the footprint without nodes lying within 5 cm of a straight
-- wall (such a node would split the end wall of a gabled roof into two skeleton faces, and neither could
-- become the gable) and its straight skeleton (lod.straight_skeleton), both WKB.
--   coverage         settings.outline_part_coverage
--   skeleton_shapes  roof:shape values whose roofs are built from the straight skeleton
--   ids              these osm.building ids alone (an update's), or NULL for all
-- Streamed by a server-side cursor: inlined into the caller's query (LANGUAGE sql, STABLE, not STRICT).
-- Example: SELECT id, roof_shape, skeleton IS NOT NULL FROM lod.building_input(0.9, ARRAY['hipped']) LIMIT 5;
CREATE OR REPLACE FUNCTION lod.building_input(coverage double precision, skeleton_shapes text[],
                                              ids bigint[] DEFAULT NULL)
RETURNS TABLE (
    id               bigint,
    osm_type         character(1),
    osm_id           bigint,
    building         text,
    height           real,
    min_height       real,
    levels           real,
    min_level        real,
    roof_levels      real,
    roof_height      real,
    footprint        bytea,
    has_parts        boolean,
    part_coverage    real,
    part             text,
    roof_shape       text,
    roof_angle       real,
    roof_direction   real,
    roof_orientation text,
    skeleton         bytea,
    roof_footprint   bytea
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    WITH src AS (
        SELECT b.*, (b.kind = 'building' AND b.part IS NULL AND b.n_parts > 0) AS has_parts FROM osm.building b
        WHERE $3 IS NULL OR b.id = ANY($3)
    )
    SELECT b.id, b.osm_type, b.osm_id, b.building, b.height, b.min_height, b.levels, b.min_level,
           b.roof_levels, b.roof_height, ST_AsBinary(g.geom), b.has_parts, b.part_coverage,
           b.part, b.roof_shape, b.roof_angle, b.roof_direction, b.roof_orientation,
           ST_AsBinary(lod.straight_skeleton(r.geom)), ST_AsBinary(r.geom)
    FROM src b
    CROSS JOIN LATERAL (SELECT CASE WHEN b.has_parts THEN lod.outline_remainder(b.id) ELSE b.geom_local END AS geom) g
    LEFT JOIN LATERAL (SELECT ST_SimplifyPreserveTopology(g.geom, 0.05) AS geom
                       WHERE b.roof_shape = ANY($2)) r ON true
    WHERE NOT (b.has_parts AND coalesce(b.part_coverage, 0) >= $1)
    ORDER BY b.id
$$;
COMMENT ON FUNCTION lod.building_input(double precision, text[], bigint[]) IS
    'Buildings and parts the lod stage draws (outlines hidden by parts covering coverage left out): tags, footprint or outline remainder (WKB), and for skeleton_shapes the roof footprint and its straight skeleton (WKB); id order; ids: those alone (NULL: all). Example: SELECT count(*) FROM lod.building_input(0.9, ARRAY[''hipped'']);';
