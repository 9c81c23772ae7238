-- tiles.drop_below_pixel(max_level, max_sse DEFAULT 16, INOUT n_dropped) -> blocks dropped as below a pixel
-- Selection by the traversal's own rule, once tiles.finish_hierarchy has measured every tile's geometric error:
-- a client draws a tile only while its screen-space error, geometric_error × H / (d × 2 tan(fov/2)), is at most
-- max_sse pixels, so wherever the tile is drawn one pixel spans at least geometric_error / max_sse metres (its
-- pixel size). A drawn block whose collapse (gen.block.collapse_m: its members shrunk to one ground point) plus
-- its members' own errors is within that pixel size, and that is isolated (no other feature the tile draws
-- within the block band's aggregation distance, gen.tolerance(gen_level): nothing it could have been merged
-- with), covers less than a pixel wherever the tile is drawn, and is dropped from the tile; its members are
-- drawn again in the tiles below. Everything else stays: blocks aggregate what is close instead of being
-- omitted one by one. The drop's error is at most geometric_error / max_sse, so the tile's geometric error
-- stays true; content_error_m takes it. The block keeps its row (the coarser bands have merged it already)
-- with the drop's error; its row in tiles.tile_content goes and the tile's content counts follow. Landmarks
-- are never in blocks, so they stay. Tiles up to max_level (NULL: all).
-- Example: CALL tiles.drop_below_pixel(NULL, 16, NULL);
CREATE OR REPLACE PROCEDURE tiles.drop_below_pixel(max_level integer, max_sse double precision DEFAULT 16,
                                                   INOUT n_dropped bigint DEFAULT NULL)
LANGUAGE plpgsql
AS $$
BEGIN
    CREATE TEMP TABLE _drop ON COMMIT DROP AS
    WITH f AS (
        -- what each block-band tile draws: its blocks, and the buildings it draws whole (landmarks: never
        -- merged, but neighbours all the same)
        SELECT k.level, k.x, k.y, k.block_id, k.footprint AS geom, gen.tolerance(k.gen_level) AS d, k.collapse_m,
               -- the bound on the distance to LOD3 once dropped: the collapse plus the members' own errors
               k.collapse_m + (k.total_error_m - k.error_m) AS total
        FROM gen.block k
        WHERE NOT k.omitted AND (max_level IS NULL OR k.level <= max_level)
        UNION ALL
        SELECT c.level, c.x, c.y, NULL, n.geom_local, gen.tolerance(t.gen_level), NULL, NULL
        FROM tiles.tile_content c JOIN tiles.tile t USING (level, x, y) JOIN osm.building n ON n.id = c.feature_id
        WHERE c.feature_kind <> 'block' AND t.gen_level <= 1 AND (max_level IS NULL OR t.level <= max_level)
    ), n AS (
        -- isolated: alone in its cluster at the band's aggregation distance, i.e. nothing else the tile draws
        -- within it. ST_ClusterDBSCAN indexes each tile's features itself (a self-join per tile compared every
        -- block with every other: quadratic in the top tiles of a large city)
        SELECT f.*, count(*) OVER (PARTITION BY level, x, y, cid) AS near
        FROM (SELECT f.*, ST_ClusterDBSCAN(geom, eps := d, minpoints := 1) OVER (PARTITION BY level, x, y) AS cid
              FROM f) f
    )
    SELECT n.block_id, n.level, n.x, n.y, n.collapse_m, n.total
    FROM n JOIN tiles.tile t ON (t.level, t.x, t.y) = (n.level, n.x, n.y)
    WHERE n.block_id IS NOT NULL AND n.near = 1 AND n.total <= t.geometric_error / max_sse;

    UPDATE gen.block k SET omitted = true, error_m = d.collapse_m, total_error_m = d.total
    FROM _drop d WHERE k.block_id = d.block_id;

    UPDATE tiles.tile t
    SET content_features = t.content_features - s.n, content_triangles = t.content_triangles - s.tri,
        content_error_m = greatest(t.content_error_m, s.err)
    FROM (SELECT c.level, c.x, c.y, count(*) AS n, sum(c.n_triangles) AS tri, max(d.total) AS err
          FROM _drop d JOIN tiles.tile_content c
            ON (c.level, c.x, c.y, c.feature_kind, c.feature_id) = (d.level, d.x, d.y, 'block', d.block_id)
          GROUP BY 1, 2, 3) s
    WHERE (t.level, t.x, t.y) = (s.level, s.x, s.y);

    DELETE FROM tiles.tile_content c USING _drop d
    WHERE (c.level, c.x, c.y, c.feature_kind, c.feature_id) = (d.level, d.x, d.y, 'block', d.block_id);

    SELECT count(*) INTO n_dropped FROM _drop;
    DROP TABLE _drop;
END
$$;
COMMENT ON PROCEDURE tiles.drop_below_pixel(integer, double precision, bigint) IS
    'Drops every drawn block that is below its tile''s pixel size (collapse_m plus its members'' errors <= geometric_error / max_sse, the smallest pixel wherever a client at max_sse draws the tile) and isolated (nothing else the tile draws within gen.tolerance(gen_level)), in tiles up to max_level (NULL: all); updates tiles.tile_content and the tiles'' content counts; returns how many. Run by the generalize stage after tiles.finish_hierarchy. Example: CALL tiles.drop_below_pixel(NULL, 16, NULL);';
