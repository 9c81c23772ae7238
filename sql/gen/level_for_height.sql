-- gen.level_for_height(height, root_height, width) -> generalization level of a tile's content
-- A tile's band follows its height in the quadtree (levels down to its deepest leaf): leaves hold LOD3 (4),
-- their parents LOD2 (3), then simplified LOD1 (2), then blocks at 5 m (1) and 10 m (0), and above those
-- coarser blocks at 20 m (-1), 40 m (-2), ... up to the root, so a coarse tile holds about as many features as
-- a fine one however large the city. The coarser bands never go past a tolerance of 1/64 of the tile's width
-- (m): one dense spot makes a deep branch and a tall tree, and its root, a few km wide, would otherwise merge
-- at tens of km; tolerance and width then double together going up. The coarsest band is -4 (160 m): the
-- closing that merges blocks costs steeply more with its distance (Liechtenstein's blocks: 2 s at 40 m, 20 s
-- at 160 m, 430 s at 640 m), and tiles that far up are refined away by any camera close enough to see a city;
-- the tiles above share band -4, merged level by level. A tree shorter than 4 (a small city)
-- spreads the bands over the levels it has, so its root still holds blocks: heights 0..root_height map to
-- 4 - round(4 × height / root_height). A parent's level is never above its children's.
-- Example: SELECT level, x, y, height, gen.level_for_height(height, 6, 24000 / 2 ^ level) FROM tiles.tile LIMIT 5;
CREATE OR REPLACE FUNCTION gen.level_for_height(height integer, root_height integer, width double precision)
RETURNS smallint
LANGUAGE sql IMMUTABLE PARALLEL SAFE STRICT
AS $$
    SELECT CASE WHEN height <= 0 THEN 4
                WHEN root_height < 4 THEN 4 - round(4.0 * height / root_height)
                WHEN height <= 4 THEN 4 - height
                -- gen.tolerance(g) = 10 / 2^g <= width / 64
                ELSE greatest(4 - height, least(0, ceil(log(2.0, (640.0 / greatest(width, 1e-3))::numeric))), -4)
           END::smallint
$$;
COMMENT ON FUNCTION gen.level_for_height(integer, integer, double precision) IS
    'Generalization level (gen.tolerance) of a tile''s content from its height above the leaves, the root''s height and the tile''s width (m): leaves 4 (LOD3), then 3, 2, 1, 0 (blocks), -1, -2, .. (coarser blocks, tolerance at most width / 64, at most 160 m) upwards; the root of a tree of any height > 0 holds blocks. Example: SELECT gen.level_for_height(1, 2, 500); -- 2';
