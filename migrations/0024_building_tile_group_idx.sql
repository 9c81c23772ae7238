-- 0024: tiles.building_tile by group_id (the outline a building or part belongs to).
-- The generalize stage fetches each batch's LOD2 meshes by group (gen.group_lod2_meshes: group_id = ANY(...)).
-- Without this index every batch scanned the whole table, so the stage grew with the square of the city:
-- 210 ms a batch on Liechtenstein, ~1.3 s on its 6x replica (53 batches).
CREATE INDEX building_tile_group_idx ON tiles.building_tile (group_id);
COMMENT ON INDEX tiles.building_tile_group_idx IS 'Buildings and parts by their outline (gen.group_lod2_meshes).';
