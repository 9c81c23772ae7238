-- 0032: a block's id names what the block is, not when it was written. It was an identity numbered in the
-- order the generalize stage wrote the blocks, so a change in one tile renumbered the blocks of every tile
-- written after it: their glbs (a block's id is its feature id and osm_id there) and their textures changed
-- with nothing in them changed. The stage now sets it to a 63-bit hash of the block's tile, band and smallest
-- member (a tile's blocks never share a member), which an update and a full rebuild give alike.
ALTER TABLE gen.block ALTER COLUMN block_id DROP IDENTITY;
COMMENT ON COLUMN gen.block.block_id IS 'Block id (also the feature id and osm_id in the tile glb): a 63-bit hash of the block''s tile (level, x, y), band (gen_level) and smallest member, the same whenever that block is made (etl/generalize/stage.py block_ids).';
