-- gen.coarse_block_clusters(band, tile_level, xs, ys, seed, skip) -> one row per block of the tiles of band
-- `band` at tile_level
-- The coarser bands (gen_level < 0, the tiles above height 4): per tile, what its children draw in its place
-- (their blocks, gen.block, and for a child in a finer band its unprotected buildings' level-2 footprints),
-- clustered at gen.tolerance(band) and merged the same way as gen.block_clusters, the inputs simplified
-- at a quarter of the distance first (the closing's cost grows steeply with vertices and distance). A
-- block's members are the union of its inputs' members and its height their area-weighted height (not the
-- inputs', whose outlines were simplified and closed). The generalize stage builds the bands upwards, so the
-- children's blocks exist. Same columns as gen.block_clusters; ordered by tile and members.
--   band        the band, tiles.tile.gen_level (< 0)
--   tile_level  the tiles' level (the top tiles of a large city share band -4, so a band runs level by level)
--   xs, ys      the tiles to make (NULL: all of them)
--   seed, skip  as gen.block_clusters: input_digest is md5 of seed, the tile and its band, and per input in
--               member order a child block's input_digest, footprint, height and error bound as made, or a finer
--               building's id, footprint, height and error bound (a child block's digest stands for its
--               members, whose footprints and heights give the block's height); a cluster in skip has only
--               its tile, n_in and input_digest (members NULL too)
-- Streamed by a server-side cursor: inlined into the caller's query (LANGUAGE sql, STABLE, not STRICT).
-- Example: SELECT x, y, count(*) FROM gen.coarse_block_clusters(-1, 2, NULL, NULL, '', NULL) GROUP BY 1, 2;
CREATE OR REPLACE FUNCTION gen.coarse_block_clusters(band integer, tile_level integer, xs integer[], ys integer[],
                                                     seed text, skip text[])
RETURNS TABLE (
    level           smallint,
    x               integer,
    y               integer,
    gen_level       smallint,
    tolerance       double precision,
    members         bigint[],
    height          real,
    hmax            double precision,
    members_error_m real,
    merged          bytea,
    joined          bytea,
    hmin            double precision,
    n_in            bigint,
    input_digest    text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    WITH t AS (
        SELECT level, x, y, gen_level, gen.tolerance(gen_level) AS d FROM tiles.tile
        WHERE gen_level = $1 AND level = $2 AND ($3 IS NULL OR (x, y) IN (SELECT * FROM unnest($3, $4)))
    ), ch AS (
        SELECT t.level, t.x, t.y, t.gen_level, t.d, c.level AS cl, c.x AS cx, c.y AS cy, c.gen_level AS cg
        FROM t JOIN tiles.tile c ON c.level = t.level + 1 AND c.x BETWEEN 2 * t.x AND 2 * t.x + 1
                               AND c.y BETWEEN 2 * t.y AND 2 * t.y + 1
    ), m AS (
        SELECT ch.level, ch.x, ch.y, ch.gen_level, ch.d, k.members, k.footprint AS geom,
               k.height::float8 AS height, k.total_error_m,
               ROW(k.input_digest, md5(ST_AsEWKB(k.footprint)), k.height, k.total_error_m)::text AS input
        -- the child's error as made: an update finds it omitted on its tile's error by the last run
        -- (tiles.omit_within_error), which the hierarchy decides again once the blocks are made
        FROM ch JOIN gen.block_as_made k ON k.level = ch.cl AND k.x = ch.cx AND k.y = ch.cy
        WHERE ch.cg <= 1
        UNION ALL
        SELECT ch.level, ch.x, ch.y, ch.gen_level, ch.d, ARRAY[f.building_id], f.geom, g.height, g.total_error_m,
               ROW(f.building_id, md5(ST_AsEWKB(f.geom)), g.height, g.total_error_m)::text
        FROM ch
        CROSS JOIN LATERAL (SELECT DISTINCT b.group_id FROM tiles.building_tiles_below(ch.cl, ch.cx, ch.cy) b) bt
        JOIN osm.building o ON o.id = bt.group_id AND NOT o.protected
        JOIN gen.footprint f ON f.building_id = bt.group_id
        JOIN gen.building_mesh g ON g.building_id = bt.group_id AND g.gen_level = 2
        WHERE ch.cg > 1
    ), c AS MATERIALIZED (
        SELECT m.*,
               ST_ClusterDBSCAN(geom, eps := d, minpoints := 1) OVER (PARTITION BY level, x, y) AS cid
        FROM m
    ), dg AS MATERIALIZED (
        SELECT level, x, y, cid, count(*) AS n_in,
               md5(ROW($5, level, x, y, gen_level, d)::text || string_agg(input, '' ORDER BY members)) AS digest
        FROM c GROUP BY level, x, y, gen_level, d, cid
    ), mem AS (
        -- the members' area-weighted height, as in bands 0 and 1, not the inputs' (simplified and closed)
        SELECT c.level, c.x, c.y, c.cid, array_agg(u ORDER BY u) AS members,
               (sum(g.height * ST_Area(f.geom) ORDER BY u) / nullif(sum(ST_Area(f.geom) ORDER BY u), 0))::real
                   AS height
        FROM c JOIN dg ON (dg.level, dg.x, dg.y, dg.cid) = (c.level, c.x, c.y, c.cid)
        CROSS JOIN LATERAL unnest(c.members) u
        JOIN gen.footprint f ON f.building_id = u
        JOIN gen.building_mesh g ON g.building_id = u AND g.gen_level = 2
        WHERE $6 IS NULL OR dg.digest <> ALL ($6)
        GROUP BY 1, 2, 3, 4
    )
    SELECT a.level, a.x, a.y, gen_level, d, mem.members, mem.height, hmax, err,
           ST_AsBinary(CASE WHEN closed IS NULL OR ST_IsEmpty(closed) THEN joined ELSE closed END),
           ST_AsBinary(joined), hmin, a.n_in, a.digest
    FROM (
        SELECT c.level, c.x, c.y, c.gen_level, c.d, c.cid, dg.digest, dg.n_in, max(c.height) AS hmax,
               min(c.height) AS hmin, max(c.total_error_m) AS err, ST_Multi(ST_Union(c.geom ORDER BY c.members))
                   AS joined,
               -- inputs simplified at d / 4 first: the closing's cost grows steeply with vertices and distance
               CASE WHEN count(*) > 1 THEN ST_Multi(ST_CollectionExtract(ST_MakeValid(ST_Buffer(
                   ST_Buffer(ST_Collect(ST_SimplifyPreserveTopology(c.geom, c.d / 4) ORDER BY c.members), c.d / 2,
                             'join=mitre mitre_limit=3'),
                   -c.d / 2, 'join=mitre mitre_limit=3')), 3)) END AS closed
        FROM c JOIN dg ON (dg.level, dg.x, dg.y, dg.cid) = (c.level, c.x, c.y, c.cid)
        WHERE $6 IS NULL OR dg.digest <> ALL ($6)
        GROUP BY c.level, c.x, c.y, c.gen_level, c.d, c.cid, dg.digest, dg.n_in
    ) a
    JOIN mem ON (mem.level, mem.x, mem.y, mem.cid) = (a.level, a.x, a.y, a.cid)
    UNION ALL
    -- a cluster the caller has: its digest alone
    SELECT t.level, t.x, t.y, t.gen_level, t.d, NULL, NULL, NULL, NULL, NULL, NULL, NULL, dg.n_in, dg.digest
    FROM dg JOIN t ON (t.level, t.x, t.y) = (dg.level, dg.x, dg.y)
    WHERE dg.digest = ANY ($6)
    -- member order, and every order-sensitive aggregate in it: the same blocks whatever order the rows come in
    ORDER BY 1, 2, 3, 6
$$;
COMMENT ON FUNCTION gen.coarse_block_clusters(integer, integer, integer[], integer[], text, text[]) IS
    'Blocks of a coarser band (band < 0) at one tile level before simplification: per tile, its children''s blocks and finer buildings clustered at gen.tolerance(band) and merged; columns as gen.block_clusters; tile and member order; only the tiles xs, ys unless NULL; a cluster whose input digest is in skip is not merged (NULL columns). Example: SELECT count(*) FROM gen.coarse_block_clusters(-1, 2, NULL, NULL, '''', NULL);';
