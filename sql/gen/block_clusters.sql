-- gen.block_clusters(levels, xs, ys, seed, skip) -> one row per block of the 10 m and 5 m bands (gen_level 0
-- and 1), before simplification
-- Per tile of those bands, its unprotected buildings (landmarks are never merged) clustered at the band's
-- distance, gen.tolerance(gen_level) (ST_ClusterDBSCAN on the level-2 footprints, gen.footprint), and each
-- cluster merged: closing by buffer-unbuffer with mitred joins, which keeps right angles; a lone building
-- keeps its simplified footprint. The generalize stage simplifies, extrudes and measures them
-- (gen.block), a tile at a time. Ordered by tile and members.
--   levels, xs, ys          the tiles to make (NULL: every tile of those bands)
--   seed                    the run's settings and code (part of input_digest)
--   skip                    input digests of blocks the caller has already (an update's kept blocks), or NULL
--   level, x, y, gen_level  the tile and its band
--   tolerance               gen.tolerance(gen_level) (m): the merge distance
--   members                 osm.building ids of the outlines merged, ascending
--   height                  the members' area-weighted height (m); hmax, hmin the largest and smallest
--   members_error_m         the largest total_error_m of the members (gen.building_mesh, gen_level 2)
--   merged                  the closed union (WKB; the union where closing left nothing)
--   joined                  the plain union of the members' footprints (WKB)
--   n_in                    inputs clustered (a block of 1 is a lone building)
--   input_digest            md5 of what the block is made from (gen.block.input_digest): seed, the tile and
--                           its band, and per member its id, level-2 footprint, height and error bound
-- A cluster whose input_digest is in skip is neither merged nor measured: its row has the tile, members, n_in
-- and input_digest, NULL for the rest (gen.coarse_block_clusters leaves its members NULL too).
-- Streamed by a server-side cursor: inlined into the caller's query (LANGUAGE sql, STABLE, not STRICT).
-- Example: SELECT level, x, y, count(*), sum(n_in) FROM gen.block_clusters(NULL, NULL, NULL, '', NULL)
--          GROUP BY 1, 2, 3;
CREATE OR REPLACE FUNCTION gen.block_clusters(levels smallint[], xs integer[], ys integer[], seed text, skip text[])
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
    n_in            bigint,
    input_digest    text
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
    ), c AS MATERIALIZED (
        SELECT m.*, ST_ClusterDBSCAN(geom, eps := d, minpoints := 1) OVER (PARTITION BY level, x, y) AS cid FROM m
    ), dg AS MATERIALIZED (
        SELECT level, x, y, cid, array_agg(building_id ORDER BY building_id) AS members, count(*) AS n_in,
               md5(ROW($4, level, x, y, gen_level, d)::text
                   || string_agg(ROW(building_id, md5(ST_AsEWKB(geom)), height, total_error_m)::text, ''
                                 ORDER BY building_id)) AS digest
        FROM c GROUP BY level, x, y, gen_level, d, cid
    )
    SELECT level, x, y, gen_level, d, members, height, hmax, err,
           ST_AsBinary(CASE WHEN closed IS NULL OR ST_IsEmpty(closed) THEN joined ELSE closed END),
           ST_AsBinary(joined), hmin, n_in, digest
    FROM (
        SELECT c.level, c.x, c.y, c.gen_level, c.d, dg.digest, dg.n_in, dg.members,
               -- every order-sensitive aggregate in member order: the same blocks, bit for bit, whatever
               -- order the rows come in (an update appends what it changed)
               (sum(c.height * c.area ORDER BY c.building_id) / nullif(sum(c.area ORDER BY c.building_id), 0))::real
                   AS height, max(c.height) AS hmax,
               min(c.height) AS hmin, max(c.total_error_m) AS err, ST_Multi(ST_Union(c.geom ORDER BY c.building_id))
                   AS joined,
               CASE WHEN count(*) > 1 THEN ST_Multi(ST_CollectionExtract(ST_MakeValid(ST_Buffer(
                   ST_Buffer(ST_Collect(c.geom ORDER BY c.building_id), c.d / 2, 'join=mitre mitre_limit=3'),
                   -c.d / 2, 'join=mitre mitre_limit=3')), 3)) END AS closed
        FROM c JOIN dg ON (dg.level, dg.x, dg.y, dg.cid) = (c.level, c.x, c.y, c.cid)
        WHERE $5 IS NULL OR dg.digest <> ALL ($5)
        GROUP BY c.level, c.x, c.y, c.gen_level, c.d, c.cid, dg.digest, dg.n_in, dg.members
    ) a
    UNION ALL
    SELECT t.level, t.x, t.y, t.gen_level, t.d, dg.members, NULL, NULL, NULL, NULL, NULL, NULL, dg.n_in, dg.digest
    FROM dg JOIN t ON (t.level, t.x, t.y) = (dg.level, dg.x, dg.y)
    WHERE dg.digest = ANY ($5)
    ORDER BY 1, 2, 3, 6  -- tile and members; not cid: DBSCAN numbers clusters in the order it meets the rows
$$;
COMMENT ON FUNCTION gen.block_clusters(smallint[], integer[], integer[], text, text[]) IS
    'Blocks of the 10 m and 5 m bands before simplification: per tile, its unprotected buildings clustered at gen.tolerance(gen_level) and merged (closed union and plain union as WKB, members, heights, members'' error, input digest); tile and member order; only the tiles listed unless NULL; a cluster whose input digest is in skip is not merged (NULL columns). Example: SELECT level, x, y, count(*) FROM gen.block_clusters(NULL, NULL, NULL, '''', NULL) GROUP BY 1, 2, 3;';
