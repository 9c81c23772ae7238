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
