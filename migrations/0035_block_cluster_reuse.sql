-- 0035: what lets an update keep the blocks of a changed tile that its change did not reach. A tile of a
-- block band (the root merges the whole city) is made again when anything below it changed, but most of its
-- clusters are the same clusters of the same inputs: each block now records a digest of what it was made
-- from, and generalize copies back the kept block of every cluster whose digest is the same instead of
-- merging, simplifying and measuring it again.
ALTER TABLE gen.block ADD COLUMN input_digest text;
COMMENT ON COLUMN gen.block.input_digest IS 'md5 (hex) of what the block was made from: the run''s settings and code, its tile and band, and per input in member order (a building''s level-2 footprint, height and error; a child block''s input_digest, footprint, height and error) (gen.block_clusters, gen.coarse_block_clusters).';
ALTER TABLE gen.kept_block ADD COLUMN input_digest text;
COMMENT ON COLUMN gen.kept_block.input_digest IS 'As gen.block.input_digest.';
-- LIKE ... INCLUDING COMMENTS copied 0032's comment, which 0034 corrected on gen.block only
COMMENT ON COLUMN gen.kept_block.block_id IS 'As gen.block.block_id.';
