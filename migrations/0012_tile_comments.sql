-- 0012: comments that name the two-argument gen.level_for_height.
COMMENT ON TABLE tiles.tile IS 'Tiles of the quadtree. Every tile has content: leaves LOD3, inner tiles the buildings below them generalized at gen.level_for_height(height, root height); children replace their parent (REPLACE).';
COMMENT ON COLUMN tiles.tile.gen_level IS 'Generalization level of the content (gen.tolerance), gen.level_for_height(height, root height): 4 LOD3 at the leaves, then 3 LOD2, 2 simplified LOD1, 1 and 0 blocks towards the root.';
