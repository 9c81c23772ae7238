-- 0031: what lets an update keep the generalized footprints and decimated meshes of the buildings it did not
-- change. The footprint and decimation batches are whole subtrees of the tile quadtree (gen.batch_units); every
-- generalize run records per batch a fingerprint of everything the batch read (its rows and LOD2 meshes, the
-- stage's settings and code) with the figures it counted. An update copies gen.footprint and gen.building_mesh
-- aside (gen.kept_*) before the stages above change them; generalize then copies back the rows of every batch
-- whose fingerprint is the same again and computes the others. The kept copies are emptied once used.
CREATE TABLE gen.unit_input (
    step        text     NOT NULL CHECK (step IN ('footprints', 'decimation')),
    level       smallint NOT NULL,
    x           integer  NOT NULL,
    y           integer  NOT NULL,
    fingerprint text,
    n_rows      integer  NOT NULL,
    stats       jsonb    NOT NULL,
    PRIMARY KEY (step, level, x, y)
);
COMMENT ON TABLE gen.unit_input IS 'Per batch of the last generalize run (a subtree of the tile quadtree, gen.batch_units): the fingerprint of what it read and what it counted (what an update compares to keep its rows).';
COMMENT ON COLUMN gen.unit_input.step IS 'footprints (level 2: gen.footprint and its gen.building_mesh row) or decimation (level 3 gen.building_mesh rows).';
COMMENT ON COLUMN gen.unit_input.level IS 'Level of the batch''s tile.';
COMMENT ON COLUMN gen.unit_input.x IS 'Column of the batch''s tile.';
COMMENT ON COLUMN gen.unit_input.y IS 'Row of the batch''s tile.';
COMMENT ON COLUMN gen.unit_input.fingerprint IS 'sha256 of the batch''s input rows, meshes, settings and code; NULL when its worker was lost and its rows were kept as mapped (never copied).';
COMMENT ON COLUMN gen.unit_input.n_rows IS 'Rows the batch wrote: buildings (footprints) or features (decimation).';
COMMENT ON COLUMN gen.unit_input.stats IS 'The figures the batch added to the run''s counts (vertices, triangles, largest error, ...).';

CREATE UNLOGGED TABLE gen.kept_footprint (LIKE gen.footprint INCLUDING COMMENTS);
CREATE INDEX ON gen.kept_footprint (building_id);
CREATE UNLOGGED TABLE gen.kept_building_mesh (LIKE gen.building_mesh INCLUDING COMMENTS);
ALTER TABLE gen.kept_building_mesh ALTER COLUMN geom SET COMPRESSION lz4;
CREATE INDEX ON gen.kept_building_mesh (building_id, gen_level);
COMMENT ON TABLE gen.kept_footprint IS 'gen.footprint as it was before an update (python -m etl update), for generalize to copy back the rows of unchanged batches; emptied once used.';
COMMENT ON TABLE gen.kept_building_mesh IS 'gen.building_mesh as it was before an update, as gen.kept_footprint.';
