-- 0045: every LOD mesh carries its envelope in EPSG:4326, computed once when the row is written, for
-- tiles.build_quadtree to take each tile's bounding region from instead of decompressing and reprojecting every
-- mesh of the city on every run (an update runs the tiles stage over the whole city): on the six copies of the
-- benchmark extract that statement took 2.8 s with the meshes and 0.5 s with their stored envelopes, the same
-- extents to the bit. A geometry, not a box2d: COPY ... (FORMAT BINARY), as the lod stage writes, needs a binary
-- input function for every column of the table, and box2d has none.
ALTER TABLE lod.building_mesh ADD COLUMN envelope_4326 geometry(Geometry, 4326)
    GENERATED ALWAYS AS (ST_Transform(ST_Envelope(geom), 4326)) STORED;
COMMENT ON COLUMN lod.building_mesh.envelope_4326 IS 'The mesh''s working-CRS envelope reprojected to EPSG:4326, as PostgreSQL computes it when the row is written: what tile regions are made of.';

-- the UNIQUE constraint on rank already indexes it
DROP INDEX lm.building_rank_idx;

-- gen.footprint_input gains `pins` (sql/gen/footprint_input.sql): the function of three arguments goes, so that
-- the reload of sql/ leaves one function of that name
DROP FUNCTION IF EXISTS gen.footprint_input(double precision, integer, bigint[]);
