-- gen.batch_units(batch) -> for every leaf tile, the unit its features go into for the generalize batches
-- The coarsest tile on the path from the root to the leaf whose subtree holds at most `batch` features (the
-- leaf itself when even it holds more): the footprint and decimation batches are whole subtrees of the
-- quadtree, so an edit changes the input of the batches where it is and no other, and an update copies the
-- others' rows (gen.unit_input) while a full run makes exactly the same batches.
--   batch  settings.gen_batch_features
-- Example: SELECT unit_level, unit_x, unit_y, count(*) FROM gen.batch_units(2000) GROUP BY 1, 2, 3;
CREATE OR REPLACE FUNCTION gen.batch_units(batch integer)
RETURNS TABLE (level smallint, x integer, y integer, unit_level smallint, unit_x integer, unit_y integer)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT l.level, l.x, l.y, coalesce(u.level, l.level), coalesce(u.x, l.x), coalesce(u.y, l.y)
    FROM tiles.tile l
    LEFT JOIN LATERAL (
        SELECT t.level, t.x, t.y
        FROM generate_series(0, l.level) AS a(lv)
        JOIN tiles.tile t ON t.level = a.lv AND t.x = l.x >> (l.level - a.lv) AND t.y = l.y >> (l.level - a.lv)
        WHERE t.n_features <= $1
        ORDER BY t.level
        LIMIT 1
    ) u ON true
    WHERE l.is_leaf
$$;
COMMENT ON FUNCTION gen.batch_units(integer) IS
    'Per leaf tile, the unit of the generalize batches: the coarsest tile on its path from the root holding at most batch features (the leaf when it holds more). Example: SELECT unit_level, unit_x, unit_y, count(*) FROM gen.batch_units(2000) GROUP BY 1, 2, 3;';
