-- api.buildings_for_tile(level, x, y, lod) -> one row per feature (building or part mesh) of a tile
-- What the exporter writes into the tile's glb: the mesh in the working CRS (POLYHEDRALSURFACE Z of
-- triangles, z = metres above ground)
-- and the properties a client shows when a building is picked, at the requested level of detail (1 block,
-- 2 roofs, 3 facades; one LOD for the whole tileset until the LOD hierarchy chooses per tile). Filtered on
-- the tiles.building_tile (level, x, y) index.
-- Example:
--   SELECT osm_type, osm_id, name, height, n_triangles FROM api.buildings_for_tile(0, 0, 0, 2) ORDER BY height DESC;
CREATE OR REPLACE FUNCTION api.buildings_for_tile(level integer, x integer, y integer, lod integer DEFAULT 1)
RETURNS TABLE (
    building_id       bigint,
    osm_type          text,
    osm_id            bigint,
    kind              text,
    building_osm_type text,
    building_osm_id   bigint,
    name              text,
    building          text,
    height            real,
    min_height        real,
    levels            real,
    roof_shape        text,
    building_colour   text,
    roof_colour       text,
    building_material text,
    roof_material     text,
    lod               smallint,
    n_triangles       integer,
    roof_height       real,
    semantics         bytea,
    geom              geometry
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT b.id, b.osm_type::text, b.osm_id, b.kind,
           coalesce(p.osm_type, b.osm_type)::text AS building_osm_type,
           coalesce(p.osm_id, b.osm_id) AS building_osm_id,
           coalesce(b.name, p.name), coalesce(b.building, p.building),
           m.height, m.min_height, b.levels, m.roof_shape,
           b.building_colour, coalesce(b.roof_colour, p.roof_colour),
           coalesce(b.building_material, p.building_material), b.roof_material,
           m.lod, m.n_triangles, m.roof_height, m.semantics, m.geom
    FROM tiles.building_tile bt
    JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod = $4
    JOIN osm.building b ON b.id = bt.building_id
    LEFT JOIN osm.building p ON p.id = b.parent_id
    WHERE bt.level = $1 AND bt.x = $2 AND bt.y = $3
    ORDER BY b.id
$$;
COMMENT ON FUNCTION api.buildings_for_tile(integer, integer, integer, integer) IS
    'Features of tile (level, x, y) at LOD lod (1-3): mesh (PolyhedralSurface Z, working CRS), per-triangle semantics and properties. Example: SELECT osm_id, name, height FROM api.buildings_for_tile(0, 0, 0, 2);';
