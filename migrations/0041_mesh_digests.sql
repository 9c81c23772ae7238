-- 0041: every stored mesh carries its digest, computed once when the row is written, for the stages'
-- fingerprints (tex.input_digests, api.export_digest, gen.footprint_unit_digests) to read instead of decompressing
-- and hashing every mesh of the city on every run: in those passes over the benchmark extract, reading the
-- meshes as WKB and hashing them was about half their time (tex.input_digests 0.83 s of 1.74 s, api.export_digest's
-- features 0.83 s of 1.16 s, one connection). An update pays for the rows it writes, not for the city.
ALTER TABLE lod.building_mesh ADD COLUMN mesh_md5 text GENERATED ALWAYS AS (md5(ST_AsEWKB(geom))) STORED;
ALTER TABLE gen.building_mesh ADD COLUMN mesh_md5 text GENERATED ALWAYS AS (md5(ST_AsEWKB(geom))) STORED;
ALTER TABLE gen.block ADD COLUMN mesh_md5 text GENERATED ALWAYS AS (md5(ST_AsEWKB(geom))) STORED;
COMMENT ON COLUMN lod.building_mesh.mesh_md5 IS 'md5 of geom''s EWKB (PostgreSQL computes it when the row is written): what fingerprints hash instead of the mesh.';
COMMENT ON COLUMN gen.building_mesh.mesh_md5 IS 'md5 of geom''s EWKB (NULL with geom): what fingerprints hash instead of the mesh.';
COMMENT ON COLUMN gen.block.mesh_md5 IS 'md5 of geom''s EWKB: what fingerprints hash instead of the mesh.';

ALTER TYPE api.feature ADD ATTRIBUTE mesh_md5 text;
COMMENT ON COLUMN api.feature.mesh_md5 IS 'md5 of geom''s EWKB, as stored with the mesh: a feature''s mesh changed exactly when it did.';

-- these return it too (sql/ creates them again)
DROP FUNCTION IF EXISTS tex.tile_features(integer, integer, integer);
DROP FUNCTION IF EXISTS tex.opening_meshes(bigint[]);
DROP FUNCTION IF EXISTS gen.group_lod2_meshes(bigint[]);
