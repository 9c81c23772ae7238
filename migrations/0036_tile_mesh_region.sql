-- 0036: the tiles stage's own region, apart from the one the generalize stage widens. An update now changes
-- tiles.tile in place (the tiles whose quadtree cell or counts changed) instead of emptying it, so that the
-- tables of the stages below (gen.block, tex.page, ...) are never emptied with it while readers read them;
-- the region the quadtree measures from the LOD meshes is kept here, and tiles.finish_hierarchy widens from it
-- (widening the previous run's region would never let a region shrink).
ALTER TABLE tiles.tile ADD COLUMN mesh_region double precision[]
    CHECK (mesh_region IS NULL OR cardinality(mesh_region) = 6);
COMMENT ON COLUMN tiles.tile.mesh_region IS 'The region of the LOD meshes of every building below the tile, as the tiles stage measures it (same layout as region); region is this widened by the generalized content (tiles.finish_hierarchy). NULL in tiles made before migration 0036.';
