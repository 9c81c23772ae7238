-- api.buildings_for_tile(level, x, y, single_lod DEFAULT NULL) -> one row per feature of tile (level, x, y)
-- What the exporter writes into the tile's glb and what api.lod_for_view lists: the features of the tile's
-- band (gen.level_for_height of its height, tiles.tile.gen_level), one branch per band:
--   4  leaves: every building and part at LOD3 (lod.building_mesh)
--   3  LOD2: every building and part at LOD2, decimated where that paid (gen.building_mesh, gen_level 3)
--   2  LOD1: every building (outline with its parts) as one solid on its simplified footprint (gen_level 2)
--   1, 0  blocks: gen.block of this tile, plus protected buildings (landmarks) at gen_level 2, never merged
--         (LOD2, gen_level 3, in the bands at or below the landmark's lm.building.lod2_band, also in band 2)
--   < 0   coarser blocks of a large city's upper tiles (20 m at -1, 40 m at -2, ...), merged from the
--         children's content; protected buildings as above
-- Only the tile's band runs (plpgsql, one IF per band). The features below a tile come from
-- tiles.building_tiles_below (GiST on the anchors, then quadtree arithmetic); protected buildings in the block
-- bands through osm.building.protected. With single_lod = 1, 2 or 3 the hierarchy
-- is ignored: leaves give every building at that LOD and inner tiles nothing (a single-LOD tileset, ADD).
-- Rows are api.feature (migrations/0020_feature_type.sql, one definition for this and tiles.lod2_features).
-- Meshes are POLYHEDRALSURFACE Z in the working CRS, z metres above ground; error_m bounds the distance to
-- the full-detail LOD3 models. Blocks have osm_type 'B' and osm_id = gen.block.block_id.
-- Example:
--   SELECT feature_kind, lod, count(*), sum(n_triangles), max(error_m)
--   FROM api.buildings_for_tile(0, 0, 0) GROUP BY 1, 2;
CREATE OR REPLACE FUNCTION api.buildings_for_tile(level integer, x integer, y integer, single_lod integer DEFAULT NULL)
RETURNS SETOF api.feature  -- migrations/0020_feature_type.sql
LANGUAGE plpgsql STABLE PARALLEL SAFE
AS $$
DECLARE
    t tiles.tile%ROWTYPE;
BEGIN
    SELECT * INTO t FROM tiles.tile tt WHERE tt.level = $1 AND tt.x = $2 AND tt.y = $3;
    IF NOT FOUND OR ($4 IS NOT NULL AND NOT t.is_leaf) THEN
        RETURN;
    END IF;
    -- only the tile's own band runs: each branch joins just the buildings below the tile it needs
    IF $4 IS NOT NULL OR t.gen_level = 4 THEN
        -- LOD3 at the leaves (or the one LOD asked for)
        RETURN QUERY
        SELECT b.kind, b.id, b.osm_type::text, b.osm_id, b.kind,
               coalesce(p.osm_type, b.osm_type)::text, coalesce(p.osm_id, b.osm_id),
               coalesce(b.name, p.name), coalesce(b.building, p.building),
               m.height, m.min_height, b.levels, m.roof_shape,
               b.building_colour, coalesce(b.roof_colour, p.roof_colour),
               coalesce(b.building_material, p.building_material), b.roof_material,
               m.lod, 4::smallint, 1, 0::real, m.n_triangles, m.roof_height, m.semantics, m.geom, m.mesh_md5
        FROM tiles.building_tiles_below($1, $2, $3) bt
        JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod = coalesce($4, 3)
        JOIN osm.building b ON b.id = bt.building_id
        LEFT JOIN osm.building p ON p.id = b.parent_id
        ORDER BY 1, 2;
    ELSIF t.gen_level = 3 THEN
        -- LOD2 band: roofs, decimated where it paid
        RETURN QUERY SELECT * FROM tiles.lod2_features($1, $2, $3) ORDER BY 1, 2;
    ELSE
        -- LOD1 band: each building with its parts as one solid on its simplified footprint; in the block
        -- bands only protected buildings (landmarks) keep it, found through their own rows. A landmark in a
        -- band at or below its lm.building.lod2_band keeps LOD2 instead (its building and parts, as band 3).
        RETURN QUERY
        WITH s AS (
            SELECT DISTINCT bt.group_id, (l.lod2_band <= t.gen_level) IS TRUE AS lod2
            FROM tiles.building_tiles_below($1, $2, $3) bt
            LEFT JOIN lm.building l ON l.building_id = bt.group_id AND l.is_landmark
            WHERE t.gen_level = 2 OR bt.group_id IN (SELECT o.id FROM osm.building o WHERE o.protected)
        )
        SELECT 'building', b.id, b.osm_type::text, b.osm_id, b.kind, b.osm_type::text, b.osm_id,
               b.name, b.building, g.height, g.min_height, b.levels, 'flat',
               b.building_colour, b.roof_colour, b.building_material, b.roof_material,
               1::smallint, 2::smallint, 1, g.total_error_m, g.n_triangles, 0::real, g.semantics, g.geom, g.mesh_md5
        FROM s
        JOIN gen.building_mesh g ON g.building_id = s.group_id AND g.gen_level = 2
        JOIN osm.building b ON b.id = s.group_id
        WHERE NOT s.lod2
        UNION ALL
        SELECT * FROM tiles.lod2_features($1, $2, $3, (SELECT array_agg(s.group_id) FROM s WHERE s.lod2))
        WHERE EXISTS (SELECT FROM s WHERE s.lod2)
        UNION ALL
        -- block bands: the tile's aggregated blocks, but for those too small for the band (selection)
        SELECT 'block', k.block_id, 'B', k.block_id, 'block', 'B', k.block_id,
               NULL, NULL, k.height, 0::real, NULL, 'flat', NULL, NULL, NULL, NULL,
               0::smallint, k.gen_level, k.n_members, k.total_error_m, k.n_triangles, 0::real, k.semantics, k.geom,
               k.mesh_md5
        FROM gen.block k
        WHERE t.gen_level <= 1 AND k.level = t.level AND k.x = t.x AND k.y = t.y AND NOT k.omitted
        ORDER BY 1, 2;
    END IF;
END
$$;
COMMENT ON FUNCTION api.buildings_for_tile(integer, integer, integer, integer) IS
    'Features of tile (level, x, y) at its band (blocks, simplified LOD1, LOD2, LOD3 at the leaves), or every building of a leaf at LOD lod when single_lod is given: mesh (PolyhedralSurface Z, working CRS), per-triangle semantics, properties, error bound. Example: SELECT feature_kind, lod, count(*) FROM api.buildings_for_tile(0, 0, 0) GROUP BY 1, 2;';
