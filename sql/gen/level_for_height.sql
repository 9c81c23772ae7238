-- gen.level_for_height(height) -> generalization level of a tile's content
-- A tile's band follows its height in the quadtree (levels down to its deepest leaf): leaves hold LOD3 (4),
-- their parents LOD2 (3), then simplified LOD1 (2), then blocks at 5 m (1) and 10 m (0) up to the root. A
-- parent is always higher than its children, so its content is never finer than theirs.
-- Example: SELECT level, x, y, height, gen.level_for_height(height) FROM tiles.tile ORDER BY level LIMIT 5;
CREATE OR REPLACE FUNCTION gen.level_for_height(height integer)
RETURNS smallint
LANGUAGE sql IMMUTABLE PARALLEL SAFE STRICT
AS $$
    SELECT greatest(0, 4 - height)::smallint
$$;
COMMENT ON FUNCTION gen.level_for_height(integer) IS
    'Generalization level (gen.tolerance) of a tile''s content from its height above the leaves: 0 -> 4 (LOD3), 1 -> 3, 2 -> 2, 3 -> 1, >= 4 -> 0. Example: SELECT gen.level_for_height(0); -- 4';
