-- 0033: what lets an update keep the blocks of the tiles it did not change. Every generalize run records per
-- block tile (bands 1 and coarser) a fingerprint of the buildings below it (gen.leaf_block_input, hashed up the
-- quadtree) with its figures (gen.unit_input, step blocks); an update copies gen.block aside (gen.kept_block)
-- and generalize copies back the blocks of every tile whose fingerprint is the same. A block the selection on
-- tile error omitted (tiles.omit_within_error) keeps its errors as built, so the copy is the block as made.
ALTER TABLE gen.unit_input DROP CONSTRAINT unit_input_step_check;
ALTER TABLE gen.unit_input ADD CONSTRAINT unit_input_step_check CHECK (step IN ('footprints', 'decimation', 'blocks'));
COMMENT ON COLUMN gen.unit_input.step IS 'footprints (level 2: gen.footprint and its gen.building_mesh row), decimation (level 3 gen.building_mesh rows) or blocks (a block tile''s gen.block rows; the tile is the unit).';

ALTER TABLE gen.block ADD COLUMN built_error_m real, ADD COLUMN built_total_error_m real;
COMMENT ON COLUMN gen.block.built_error_m IS 'error_m as the block was made, when tiles.omit_within_error omitted it since (error_m is then the omission''s); NULL otherwise.';
COMMENT ON COLUMN gen.block.built_total_error_m IS 'total_error_m as the block was made, when tiles.omit_within_error omitted it since; NULL otherwise.';

CREATE UNLOGGED TABLE gen.kept_block (LIKE gen.block INCLUDING COMMENTS);
CREATE INDEX ON gen.kept_block (level, x, y);
COMMENT ON TABLE gen.kept_block IS 'gen.block as it was before an update (python -m etl update), for generalize to copy back the blocks of unchanged tiles; emptied once used.';
