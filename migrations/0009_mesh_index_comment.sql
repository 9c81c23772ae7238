-- 0009: the (lod) index is never chosen (three values; the primary key (building_id, lod) serves the joins)
-- but every COPY row paid for it; the opening area comment names both opening styles.
DROP INDEX lod.building_mesh_lod_idx;
COMMENT ON COLUMN lod.building_mesh.opening_area_m2 IS 'LOD3: area of the window and door surfaces, panels or boxes (m²); 0 below LOD3.';
