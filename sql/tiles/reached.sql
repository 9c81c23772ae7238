-- tiles.reached(p_building_ids, p_levels, p_xs, p_ys)
-- The tiles that buildings and tiles reach: those tiles and the leaves of those buildings (placed by
-- tiles.building_tile as it is now: a building that moved or went is in the tiles stage's run as the tiles it
-- left), each with its ancestors that exist. Every tile above a building stands for it, so these are the tiles
-- whose content a change of those buildings and tiles can change (core/changes.py).
-- Example: SELECT * FROM tiles.reached(ARRAY[123]::bigint[], '{}', '{}', '{}');
CREATE OR REPLACE FUNCTION tiles.reached(p_building_ids bigint[], p_levels integer[], p_xs integer[],
                                         p_ys integer[])
RETURNS TABLE (level integer, x integer, y integer)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    WITH b AS (SELECT unnest(p_building_ids) AS id),
    leaf AS (
        SELECT bt.level, bt.x, bt.y FROM tiles.building_tile bt WHERE bt.building_id IN (SELECT id FROM b)
        UNION
        SELECT bt.level, bt.x, bt.y FROM tiles.building_tile bt WHERE bt.group_id IN (SELECT id FROM b)
        UNION
        SELECT * FROM unnest(p_levels, p_xs, p_ys)
    )
    SELECT DISTINCT (l.level - k)::integer, l.x >> k, l.y >> k
    FROM leaf l CROSS JOIN LATERAL generate_series(0, l.level) k
    JOIN tiles.tile t ON (t.level, t.x, t.y) = (l.level - k, l.x >> k, l.y >> k)
$$;
COMMENT ON FUNCTION tiles.reached(bigint[], integer[], integer[], integer[]) IS
    'The tiles that the buildings p_building_ids (their leaves) and the tiles (p_levels[i], p_xs[i], p_ys[i]) reach, with their ancestors: whose content a change of those can change.';
