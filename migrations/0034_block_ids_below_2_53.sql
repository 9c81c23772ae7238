-- 0034: a block's id as the generalize stage now makes it (0032 described a 63-bit hash, which a JavaScript
-- client cannot read exactly: loaders.gl gave it back as a string).
COMMENT ON COLUMN gen.block.block_id IS 'Block id (also the feature id and osm_id in the tile glb): its smallest member m and its tile''s level packed as (2m, or -2m + 1 for a relation''s negative id) * 32 + level, the same whenever that block is made and below 2^53 (etl/generalize/stage.py block_ids).';
