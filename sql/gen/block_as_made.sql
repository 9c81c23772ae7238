-- gen.block_as_made: every block as the generalize stage made it, before the selection on tile error
-- gen.block keeps a block that tiles.omit_within_error omitted with the omission's errors and its own beside
-- (built_error_m, built_total_error_m). Everything that reads a block before the hierarchy decides those
-- omissions again (an update finds the last run's still there) reads it here: omitted only when too small for
-- its band, error_m and total_error_m its own; omitted_on_error says whether the last decision omitted it.
-- Example:
--   SELECT gen_level, count(*) FILTER (WHERE omitted_on_error), max(total_error_m) FROM gen.block_as_made
--   GROUP BY 1 ORDER BY 1;
CREATE OR REPLACE VIEW gen.block_as_made AS
SELECT k.block_id, k.level, k.x, k.y, k.gen_level, k.members, k.n_members, k.footprint, k.geom, k.semantics,
       k.n_triangles, k.height, k.omitted AND k.built_error_m IS NULL AS omitted,
       coalesce(k.built_error_m, k.error_m) AS error_m,
       coalesce(k.built_total_error_m, k.total_error_m) AS total_error_m,
       k.collapse_m, k.input_digest, k.mesh_md5, k.built_error_m IS NOT NULL AS omitted_on_error
FROM gen.block k;
COMMENT ON VIEW gen.block_as_made IS
    'gen.block as made, before the selection on tile error: omitted for its band only, its own errors; omitted_on_error: the last decision omitted it. Example: SELECT count(*) FILTER (WHERE omitted_on_error) FROM gen.block_as_made;';
COMMENT ON COLUMN gen.block_as_made.block_id IS 'gen.block.block_id (also the feature id and osm_id in the tile glb).';
COMMENT ON COLUMN gen.block_as_made.level IS 'gen.block.level: tile level (the block is content of tile (level, x, y)).';
COMMENT ON COLUMN gen.block_as_made.x IS 'gen.block.x: tile column.';
COMMENT ON COLUMN gen.block_as_made.y IS 'gen.block.y: tile row.';
COMMENT ON COLUMN gen.block_as_made.gen_level IS 'gen.block.gen_level: the generalization level (aggregation distance and outline tolerance gen.tolerance(gen_level)).';
COMMENT ON COLUMN gen.block_as_made.members IS 'gen.block.members: osm.building.id of the member buildings (outlines).';
COMMENT ON COLUMN gen.block_as_made.n_members IS 'gen.block.n_members: number of member buildings.';
COMMENT ON COLUMN gen.block_as_made.footprint IS 'gen.block.footprint: merged and simplified outline in the working CRS.';
COMMENT ON COLUMN gen.block_as_made.geom IS 'gen.block.geom: the block solid (flat roof), POLYHEDRALSURFACE Z, working CRS.';
COMMENT ON COLUMN gen.block_as_made.semantics IS 'gen.block.semantics: one lod.surface_type code per triangle.';
COMMENT ON COLUMN gen.block_as_made.n_triangles IS 'gen.block.n_triangles: triangles in geom.';
COMMENT ON COLUMN gen.block_as_made.height IS 'gen.block.height: roof height above ground (m), the members'' heights weighted by their footprint areas.';
COMMENT ON COLUMN gen.block_as_made.omitted IS 'Omitted as made: gen.block.omitted unless tiles.omit_within_error set it (built_error_m not NULL), i.e. true only for a block too small for its band (collapse_m <= gen.tolerance(gen_level)).';
COMMENT ON COLUMN gen.block_as_made.error_m IS 'The block''s own error as made (gen.block.built_error_m when it was omitted on error since, else gen.block.error_m): Hausdorff distance (m) to what it replaces.';
COMMENT ON COLUMN gen.block_as_made.total_error_m IS 'The block''s own bound as made (gen.block.built_total_error_m when it was omitted on error since, else gen.block.total_error_m) on the distance (m) to the full-detail LOD3 models.';
COMMENT ON COLUMN gen.block_as_made.collapse_m IS 'gen.block.collapse_m: error (m) of omitting the block, its members collapsed to one ground point.';
COMMENT ON COLUMN gen.block_as_made.input_digest IS 'gen.block.input_digest: md5 (hex) of what the block was made from.';
COMMENT ON COLUMN gen.block_as_made.mesh_md5 IS 'gen.block.mesh_md5: md5 of geom''s EWKB.';
COMMENT ON COLUMN gen.block_as_made.omitted_on_error IS 'True when the last tiles.omit_within_error omitted the block (gen.block.built_error_m is set): its tile does not draw it though it was made to be drawn.';
