-- 0042: texture pages and UVs carry the md5 of their bytes, computed once when the row is written, for the
-- export's fingerprint of a tile (api.export_digest) to read instead of reading and hashing every page and UV of
-- the city on every export: on the benchmark extract the UVs alone are 63 MB, 0.32 s to hash (one connection),
-- paid by every update whatever it changed. An update pays for the rows it writes, not for the city.
ALTER TABLE tex.page ADD COLUMN bytes_md5 text GENERATED ALWAYS AS (md5(bytes)) STORED;
ALTER TABLE tex.page ADD COLUMN ktx2_md5 text GENERATED ALWAYS AS (md5(ktx2)) STORED;
ALTER TABLE tex.feature_uv ADD COLUMN uv_md5 text GENERATED ALWAYS AS (md5(page || uv)) STORED;
COMMENT ON COLUMN tex.page.bytes_md5 IS 'md5 of bytes (PostgreSQL computes it when the row is written): what the export''s fingerprint hashes instead of the page.';
COMMENT ON COLUMN tex.page.ktx2_md5 IS 'md5 of ktx2 (NULL with ktx2): what the export''s fingerprint hashes instead of the page.';
COMMENT ON COLUMN tex.feature_uv.uv_md5 IS 'md5 of page || uv (their lengths follow from n_triangles): what the export''s fingerprint hashes instead of them.';

-- these return it too (sql/ creates them again)
DROP FUNCTION IF EXISTS api.tile_pages(integer, integer, integer, text);
DROP FUNCTION IF EXISTS api.tile_uvs(integer, integer, integer);
-- returns building_id too, so gen.footprint_unit_digests orders by it instead of WITH ORDINALITY (sql/ creates it
-- again)
DROP FUNCTION IF EXISTS gen.group_lod2_meshes(bigint[]);
