-- 0043: what a run of a stage in an update changed, for the stages after it to read again only the tiles that
-- holds (core/changes.py). Until now every update's generalize measured the hierarchy of every tile, and textures
-- and the export fingerprinted every tile's features, whatever the change: three passes over the city each
-- update paid (about 2.5 s on the benchmark extract, most of a one-building update's generalize and export).
-- A run with no row here (a full run, a run that died, a run from before this migration) may have changed
-- anything: a stage after it reads every tile, as before.
CREATE TABLE meta.run_dirty (
    run_id       bigint   PRIMARY KEY REFERENCES meta.pipeline_run (run_id) ON DELETE CASCADE,
    building_ids bigint[] NOT NULL DEFAULT '{}',
    levels       integer[] NOT NULL DEFAULT '{}',
    xs           integer[] NOT NULL DEFAULT '{}',
    ys           integer[] NOT NULL DEFAULT '{}',
    CHECK (cardinality(levels) = cardinality(xs) AND cardinality(xs) = cardinality(ys))
);
COMMENT ON TABLE meta.run_dirty IS 'What a run of a stage in an update changed: the buildings (osm.building ids: every tile that draws one of them, its leaf and the leaf''s ancestors, is reached) and the tiles it changed. A run without a row may have changed anything.';
COMMENT ON COLUMN meta.run_dirty.run_id IS 'The run (meta.pipeline_run).';
COMMENT ON COLUMN meta.run_dirty.building_ids IS 'Buildings whose rows the run changed (an outline or a part: the whole group is reached).';
COMMENT ON COLUMN meta.run_dirty.levels IS 'Tiles the run changed, with xs and ys (the same length): (levels[i], xs[i], ys[i]).';
COMMENT ON COLUMN meta.run_dirty.xs IS 'The x of each tile of levels.';
COMMENT ON COLUMN meta.run_dirty.ys IS 'The y of each tile of levels.';

-- take the tiles to measure (sql/ creates them again)
DROP PROCEDURE IF EXISTS tiles.finish_hierarchy(double precision);
DROP PROCEDURE IF EXISTS tiles.omit_within_error(integer, bigint);
