-- gen.coarse_bands(max_level DEFAULT NULL) -> (gen_level, level) of every coarser band's tiles, in build order
-- The coarser bands (gen_level < 0) and the tile levels they hold, finest band and deepest level first: the
-- order the generalize stage builds them in (gen.coarse_block_clusters), each from its children's content.
--   max_level  only tiles at levels <= max_level (NULL: all)
-- Example: SELECT * FROM gen.coarse_bands();
CREATE OR REPLACE FUNCTION gen.coarse_bands(max_level integer DEFAULT NULL)
RETURNS TABLE (
    gen_level smallint,
    level     smallint
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT DISTINCT t.gen_level, t.level FROM tiles.tile t
    WHERE t.gen_level < 0 AND ($1 IS NULL OR t.level <= $1)
    ORDER BY 1 DESC, 2 DESC
$$;
COMMENT ON FUNCTION gen.coarse_bands(integer) IS
    'The coarser bands (gen_level < 0) and their tile levels (up to max_level; NULL: all), finest band and deepest level first: the generalize stage''s build order. Example: SELECT * FROM gen.coarse_bands();';
