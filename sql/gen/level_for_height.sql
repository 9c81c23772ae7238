-- gen.level_for_height(height, root_height) -> generalization level of a tile's content
-- A tile's band follows its height in the quadtree (levels down to its deepest leaf): leaves hold LOD3 (4),
-- their parents LOD2 (3), then simplified LOD1 (2), then blocks at 5 m (1) and 10 m (0) up to the root. A tree
-- shorter than that (root_height < 4, a small city) spreads the bands over the levels it has, so its root
-- still holds blocks: heights 0..root_height map to 4 - round(4 × height / root_height). A parent is always
-- higher than its children, so its content is never finer than theirs.
-- Example: SELECT level, x, y, height, gen.level_for_height(height, 6) FROM tiles.tile ORDER BY level LIMIT 5;
CREATE OR REPLACE FUNCTION gen.level_for_height(height integer, root_height integer)
RETURNS smallint
LANGUAGE sql IMMUTABLE PARALLEL SAFE STRICT
AS $$
    SELECT CASE WHEN height <= 0 THEN 4
                WHEN root_height >= 4 THEN greatest(0, 4 - height)
                ELSE 4 - round(4.0 * height / root_height) END::smallint
$$;
COMMENT ON FUNCTION gen.level_for_height(integer, integer) IS
    'Generalization level (gen.tolerance) of a tile''s content from its height above the leaves and the root''s height: leaves 4 (LOD3), then 3, 2, 1, 0 (blocks) upwards; the root of a tree of any height > 0 holds blocks. Example: SELECT gen.level_for_height(1, 2); -- 2';
