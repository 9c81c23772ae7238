-- 0004: meshes per building and level of detail.
CREATE TABLE lod.building_mesh (
    building_id   bigint   NOT NULL REFERENCES osm.building (id) ON DELETE CASCADE,
    lod           smallint NOT NULL CHECK (lod BETWEEN 0 AND 4),
    geom          geometry(PolyhedralSurfaceZ) NOT NULL,
    n_triangles   integer  NOT NULL,
    min_height    real     NOT NULL,
    height        real     NOT NULL,
    height_source text     NOT NULL CHECK (height_source IN ('height', 'levels', 'type_default', 'default')),
    volume_m3     double precision NOT NULL,
    PRIMARY KEY (building_id, lod)
);
CREATE INDEX building_mesh_geom_idx ON lod.building_mesh USING gist (geom);
COMMENT ON TABLE lod.building_mesh IS 'Closed, outward-oriented triangulated solids, one per building or part and LOD, in the working CRS (meta.dataset.srid); z is metres above ground.';
COMMENT ON COLUMN lod.building_mesh.building_id IS 'osm.building.id.';
COMMENT ON COLUMN lod.building_mesh.lod IS 'Level of detail: 1 = block extruded from min_height to height.';
COMMENT ON COLUMN lod.building_mesh.geom IS 'The solid as a POLYHEDRALSURFACE Z of triangles wound counter-clockwise seen from outside; ST_Volume(ST_MakeSolid(geom)) works on it.';
COMMENT ON COLUMN lod.building_mesh.n_triangles IS 'Number of triangles in geom.';
COMMENT ON COLUMN lod.building_mesh.min_height IS 'Bottom of the solid above ground (m).';
COMMENT ON COLUMN lod.building_mesh.height IS 'Top of the solid above ground (m).';
COMMENT ON COLUMN lod.building_mesh.height_source IS 'Where height came from: height tag, levels × level height, a default for the building type, or the global default.';
COMMENT ON COLUMN lod.building_mesh.volume_m3 IS 'Enclosed volume (m³) of the solid.';
