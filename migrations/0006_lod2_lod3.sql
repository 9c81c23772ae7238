-- 0006: LOD2 (roofs) and LOD3 (facades) meshes share lod.building_mesh; per-triangle surface semantics.
CREATE TABLE lod.surface_type (
    code smallint PRIMARY KEY,
    name text NOT NULL UNIQUE
);
INSERT INTO lod.surface_type (code, name) VALUES
    (0, 'ground'), (1, 'wall'), (2, 'roof'), (3, 'window'), (4, 'door');
COMMENT ON TABLE lod.surface_type IS 'Surface semantic codes of lod.building_mesh.semantics (CityGML-like thematic surfaces).';
COMMENT ON COLUMN lod.surface_type.code IS 'The byte stored per triangle in lod.building_mesh.semantics.';
COMMENT ON COLUMN lod.surface_type.name IS 'ground (bottom surface), wall, roof, window or door.';

ALTER TABLE lod.building_mesh
    ADD COLUMN semantics          bytea,
    ADD COLUMN roof_shape         text,
    ADD COLUMN roof_height        real,
    ADD COLUMN roof_engine        text,
    ADD COLUMN ground_area_m2     double precision,
    ADD COLUMN wall_area_m2       double precision,
    ADD COLUMN roof_area_m2       double precision,
    ADD COLUMN opening_area_m2    double precision,
    ADD COLUMN n_windows          integer,
    ADD COLUMN n_doors            integer,
    ADD COLUMN watertight         boolean,
    ADD COLUMN winding_consistent boolean;
COMMENT ON COLUMN lod.building_mesh.lod IS 'Level of detail: 1 = block extruded from min_height to height; 2 = walls and the roof:shape roof; 3 = LOD2 plus windows and doors as geometry.';
COMMENT ON COLUMN lod.building_mesh.geom IS 'The solid as a POLYHEDRALSURFACE Z of triangles wound counter-clockwise seen from outside. LOD1/LOD2 are one closed shell (ST_Volume(ST_MakeSolid(geom)) works); LOD3 adds one closed box per window and door.';
COMMENT ON COLUMN lod.building_mesh.semantics IS 'One byte per triangle of geom, in order: its surface type (lod.surface_type.code). get_byte(semantics, i) is triangle i+1.';
COMMENT ON COLUMN lod.building_mesh.roof_shape IS 'Roof shape drawn: the roof:shape catalogue value, flat for untagged and unknown values (see meta.building_diagnostic).';
COMMENT ON COLUMN lod.building_mesh.roof_height IS 'Roof height drawn (m): roof:height, else from roof:angle, else roof:levels × level height, else the shape''s default pitch; 0 for flat roofs and LOD1.';
COMMENT ON COLUMN lod.building_mesh.roof_engine IS 'How the roof was built: flat, skeleton (straight skeleton faces), apex (rings towards a centre), field (height field along roof:direction).';
COMMENT ON COLUMN lod.building_mesh.ground_area_m2 IS 'Area of the ground (bottom) triangles (m²).';
COMMENT ON COLUMN lod.building_mesh.wall_area_m2 IS 'Area of the wall triangles, gables included (m²).';
COMMENT ON COLUMN lod.building_mesh.roof_area_m2 IS 'Area of the roof triangles, slopes measured along the slope (m²).';
COMMENT ON COLUMN lod.building_mesh.opening_area_m2 IS 'LOD3: area of the window and door boxes'' surfaces (m²); 0 below LOD3.';
COMMENT ON COLUMN lod.building_mesh.n_windows IS 'LOD3: number of windows; 0 below LOD3.';
COMMENT ON COLUMN lod.building_mesh.n_doors IS 'LOD3: number of doors; 0 below LOD3.';
COMMENT ON COLUMN lod.building_mesh.watertight IS 'Every edge shared by exactly two triangles (trimesh is_watertight), measured by the lod stage.';
COMMENT ON COLUMN lod.building_mesh.winding_consistent IS 'Shared edges run in opposite directions (trimesh is_winding_consistent), measured by the lod stage.';
CREATE INDEX building_mesh_lod_idx ON lod.building_mesh (lod);
