-- gen.block_clusters(levels, xs, ys) -> one row per block of the 10 m and 5 m bands (gen_level 0 and 1), before
-- simplification
-- Per tile of those bands, its unprotected buildings (landmarks are never merged) clustered at the band's
-- distance, gen.tolerance(gen_level) (ST_ClusterDBSCAN on the level-2 footprints, gen.footprint), and each
-- cluster merged: closing by buffer-unbuffer with mitred joins, which keeps right angles; a lone building
-- keeps its simplified footprint. The generalize stage simplifies, extrudes and measures them
-- (gen.block), a tile at a time. Ordered by tile and members.
--   levels, xs, ys          the tiles to make (NULL: every tile of those bands)
--   level, x, y, gen_level  the tile and its band
--   tolerance               gen.tolerance(gen_level) (m): the merge distance
--   members                 osm.building ids of the outlines merged, ascending
--   height                  the members' area-weighted height (m); hmax, hmin the largest and smallest
--   members_error_m         the largest total_error_m of the members (gen.building_mesh, gen_level 2)
--   merged                  the closed union (WKB; the union where closing left nothing)
--   joined                  the plain union of the members' footprints (WKB)
--   n_in                    inputs clustered (a block of 1 is a lone building)
-- Streamed by a server-side cursor: inlined into the caller's query (LANGUAGE sql, STABLE, not STRICT).
-- Example: SELECT level, x, y, count(*), sum(n_in) FROM gen.block_clusters(NULL, NULL, NULL) GROUP BY 1, 2, 3;
CREATE OR REPLACE FUNCTION gen.block_clusters(levels smallint[], xs integer[], ys integer[])
RETURNS TABLE (
    level           smallint,
    x               integer,
    y               integer,
    gen_level       smallint,
    tolerance       double precision,
    members         bigint[],
    height          real,
    hmax            real,
    members_error_m real,
    merged          bytea,
    joined          bytea,
    hmin            real,
    n_in            bigint
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    WITH t AS (
        SELECT level, x, y, gen_level, gen.tolerance(gen_level) AS d FROM tiles.tile
        WHERE gen_level IN (0, 1) AND ($1 IS NULL OR (level, x, y) IN (SELECT * FROM unnest($1, $2, $3)))
    ), m AS (
        SELECT t.level, t.x, t.y, t.gen_level, t.d, f.building_id, f.geom, g.height, g.total_error_m,
               ST_Area(f.geom) AS area
        FROM t
        CROSS JOIN LATERAL (SELECT DISTINCT b.group_id FROM tiles.building_tiles_below(t.level, t.x, t.y) b) bt
        JOIN osm.building o ON o.id = bt.group_id AND NOT o.protected
        JOIN gen.footprint f ON f.building_id = bt.group_id
        JOIN gen.building_mesh g ON g.building_id = bt.group_id AND g.gen_level = 2
    ), c AS (
        SELECT m.*, ST_ClusterDBSCAN(geom, eps := d, minpoints := 1) OVER (PARTITION BY level, x, y) AS cid FROM m
    )
    SELECT level, x, y, gen_level, d, members, height, hmax, err,
           ST_AsBinary(CASE WHEN closed IS NULL OR ST_IsEmpty(closed) THEN joined ELSE closed END),
           ST_AsBinary(joined), hmin, n_in
    FROM (
        SELECT level, x, y, gen_level, d, cid, count(*) AS n_in,
               array_agg(building_id ORDER BY building_id) AS members,
               -- every order-sensitive aggregate in member order: the same blocks, bit for bit, whatever
               -- order the rows come in (an update appends what it changed)
               (sum(height * area ORDER BY building_id) / nullif(sum(area ORDER BY building_id), 0))::real
                   AS height, max(height) AS hmax,
               min(height) AS hmin, max(total_error_m) AS err, ST_Multi(ST_Union(geom ORDER BY building_id))
                   AS joined,
               CASE WHEN count(*) > 1 THEN ST_Multi(ST_CollectionExtract(ST_MakeValid(ST_Buffer(
                   ST_Buffer(ST_Collect(geom ORDER BY building_id), d / 2, 'join=mitre mitre_limit=3'),
                   -d / 2, 'join=mitre mitre_limit=3')), 3)) END AS closed
        FROM c
        GROUP BY level, x, y, gen_level, d, cid
    ) a
    ORDER BY level, x, y, members  -- not cid: DBSCAN numbers clusters in the order it meets the rows
$$;
COMMENT ON FUNCTION gen.block_clusters(smallint[], integer[], integer[]) IS
    'Blocks of the 10 m and 5 m bands before simplification: per tile, its unprotected buildings clustered at gen.tolerance(gen_level) and merged (closed union and plain union as WKB, members, heights, members'' error); tile and member order; only the tiles listed unless NULL. Example: SELECT level, x, y, count(*) FROM gen.block_clusters(NULL, NULL, NULL) GROUP BY 1, 2, 3;';
