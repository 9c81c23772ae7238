-- gen.leaf_block_input() -> per leaf tile, a digest of what the blocks above it read of its buildings
-- For every building (an outline with its parts) of the leaf: its id, whether it is protected (a landmark,
-- never merged), its level-2 footprint (gen.footprint) and its level-2 height and error bound
-- (gen.building_mesh): everything gen.block_clusters and gen.coarse_block_clusters read of it. The generalize
-- stage hashes these up the quadtree (a tile's digest from its children's), and an update copies the blocks of
-- every tile whose digest is the one the last run recorded (gen.unit_input, step blocks) instead of making them.
-- Example: SELECT level, x, y, digest FROM gen.leaf_block_input() LIMIT 5;
CREATE OR REPLACE FUNCTION gen.leaf_block_input()
RETURNS TABLE (level smallint, x integer, y integer, digest text)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT bt.level, bt.x, bt.y,
           md5(string_agg(ROW(bt.group_id, o.protected, md5(ST_AsEWKB(f.geom)), g.height, g.total_error_m)::text, ''
                          ORDER BY bt.group_id))
    FROM (SELECT DISTINCT b.level, b.x, b.y, b.group_id FROM tiles.building_tile b) bt
    JOIN osm.building o ON o.id = bt.group_id
    LEFT JOIN gen.footprint f ON f.building_id = bt.group_id
    LEFT JOIN gen.building_mesh g ON g.building_id = bt.group_id AND g.gen_level = 2
    GROUP BY 1, 2, 3
$$;
COMMENT ON FUNCTION gen.leaf_block_input() IS
    'Per leaf tile, md5 of what the block bands read of its buildings (id, protected, level-2 footprint, height and error bound), for the generalize stage''s block fingerprints. Example: SELECT level, x, y, digest FROM gen.leaf_block_input() LIMIT 5;';
