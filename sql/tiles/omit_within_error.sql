-- tiles.omit_within_error(max_level, INOUT n_omitted, levels, xs, ys) -> blocks omitted by the selection on tile error
-- Selection bounded by what a tile already claims: once tiles.finish_hierarchy has measured every tile's
-- geometric error (the largest error of its content and of its children), a drawn block whose omission error
-- (gen.block.collapse_m: its members collapsed to one ground point) plus its members' own errors is within
-- that error is omitted as well. The tile's geometric error stays true, so no camera refines differently, and
-- a coarse tile seen from kilometres away stops drawing thousands of blocks a few pixels big (a block band's
-- largest errors come from towers flattened into blocks, tens of metres; most blocks are a few houses).
-- Landmarks are never in blocks, so they stay. The block keeps its row (the coarser bands have merged it already)
-- with the omission's error and its errors as made beside (built_error_m, built_total_error_m); its row in
-- tiles.tile_content goes, and the tile's content counts and content error follow. Decided from the errors as made
-- (gen.block_as_made), so a block the last run omitted is omitted again or put back as made: only the blocks whose
-- omission changes are written (an update wrote each omitted block twice, back as made and omitted again: 24,454 row
-- versions in the 1 % update of the benchmark extract). The tiles' content counts are those of their blocks as made,
-- as tiles.finish_hierarchy, which calls it, counts them. Tiles up to max_level (NULL: all); only the tiles
-- (levels[i], xs[i], ys[i]) when levels is given (those tiles.finish_hierarchy measured again, whose content counts
-- it has just set: another tile's were counted, and its blocks omitted, by the run that measured it).
-- Example: CALL tiles.omit_within_error(NULL, NULL);
CREATE OR REPLACE PROCEDURE tiles.omit_within_error(max_level integer, INOUT n_omitted bigint DEFAULT NULL,
                                                    levels integer[] DEFAULT NULL, xs integer[] DEFAULT NULL,
                                                    ys integer[] DEFAULT NULL)
LANGUAGE plpgsql
AS $$
BEGIN
    CREATE TEMP TABLE _omit_scope ON COMMIT DROP AS
    SELECT t.level, t.x, t.y FROM tiles.tile t
    WHERE (max_level IS NULL OR t.level <= max_level)
      AND (levels IS NULL OR (t.level, t.x, t.y) IN (SELECT * FROM unnest(levels, xs, ys)));
    ALTER TABLE _omit_scope ADD PRIMARY KEY (level, x, y);

    -- the blocks drawn as made (not omitted for their band) within their tile's error, from their errors as made
    -- (an update finds the last run's omissions still there: tiles.finish_hierarchy)
    CREATE TEMP TABLE _omit ON COMMIT DROP AS
    SELECT k.block_id, k.level, k.x, k.y, k.collapse_m, b.total, k.omitted_on_error AS already
    FROM gen.block_as_made k JOIN tiles.tile t ON (t.level, t.x, t.y) = (k.level, k.x, k.y)
    JOIN _omit_scope o ON (o.level, o.x, o.y) = (t.level, t.x, t.y)
    -- the bound on the distance to LOD3 once omitted: the omission plus the members' own errors
    CROSS JOIN LATERAL (SELECT k.collapse_m + (k.total_error_m - k.error_m) AS total) b
    WHERE NOT k.omitted AND b.total <= t.geometric_error;

    -- only the blocks whose omission changes are written. Back as made: those no longer within the error
    UPDATE gen.block k SET omitted = false, error_m = k.built_error_m, total_error_m = k.built_total_error_m,
                           built_error_m = NULL, built_total_error_m = NULL
    FROM _omit_scope t
    WHERE (t.level, t.x, t.y) = (k.level, k.x, k.y) AND k.built_error_m IS NOT NULL
      AND NOT EXISTS (SELECT FROM _omit o WHERE o.block_id = k.block_id);
    -- omitted, the errors as made kept beside: an update copies the block as it was made
    -- (etl/generalize/stage.py); one omitted already has these values from the same row
    UPDATE gen.block k SET omitted = true, error_m = o.collapse_m, total_error_m = o.total,
                           built_error_m = k.error_m, built_total_error_m = k.total_error_m
    FROM _omit o WHERE k.block_id = o.block_id AND NOT o.already;

    UPDATE tiles.tile t
    SET content_features = t.content_features - s.n, content_triangles = t.content_triangles - s.tri,
        content_error_m = greatest(t.content_error_m, s.err)
    -- every drawn block is in its tile's content counts (tiles.finish_hierarchy), whether or not its
    -- tiles.tile_content row is written yet
    FROM (SELECT o.level, o.x, o.y, count(*) AS n, sum(k.n_triangles) AS tri, max(o.total) AS err
          FROM _omit o JOIN gen.block k ON k.block_id = o.block_id
          GROUP BY 1, 2, 3) s
    WHERE (t.level, t.x, t.y) = (s.level, s.x, s.y);

    DELETE FROM tiles.tile_content c USING _omit o
    WHERE (c.level, c.x, c.y, c.feature_kind, c.feature_id) = (o.level, o.x, o.y, 'block', o.block_id);

    SELECT count(*) INTO n_omitted FROM _omit;
    DROP TABLE _omit;
    DROP TABLE _omit_scope;
END
$$;
COMMENT ON PROCEDURE tiles.omit_within_error(integer, bigint, integer[], integer[], integer[]) IS
    'Omits every block drawn as made whose omission error (gen.block.collapse_m) is within its tile''s geometric error, in tiles up to max_level (NULL: all) or in the tiles given (levels, xs, ys), puts back as made those omitted no more, and updates tiles.tile_content and the tiles'' content counts (those of the blocks as made); returns how many are omitted. Called by tiles.finish_hierarchy. Example: CALL tiles.omit_within_error(NULL, NULL);';
