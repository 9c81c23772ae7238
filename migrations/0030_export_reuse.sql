-- 0030: what lets an export copy the tiles whose content did not change. Every published file that is a tile's
-- content records the fingerprint of its input: api.export_digest (the tile's features, landmark metadata,
-- atlas pages and UVs) with the exporter's code, settings and options and the tile's place in the tree. The
-- next export of the same tileset compares, and copies the glb of a tile whose fingerprint is the same
-- (from the export directory, or from pub.blob) instead of building it again.
ALTER TABLE pub.file ADD COLUMN input_digest text;
COMMENT ON COLUMN pub.file.input_digest IS 'For a tile''s glb: sha256 of what the export built it from (api.export_digest, the exporter''s code, settings and options, the tile''s record); the next export of the tileset copies the glb when it is the same. NULL for tileset.json and subtrees, which are always written.';
