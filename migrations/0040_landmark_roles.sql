-- 0040: each building's part in the landmarks' exaggeration, stored by the landmarks stage (lm.fill_exaggeration)
-- instead of computed by lm.exaggeration_role for every feature of every tile the exporter reads: that lateral
-- call was more than half of api.export_digest's time (Liechtenstein, every tile, one connection: 1.0 s of
-- 1.85 s), paid again by every update's export and by every glb the database server builds.
CREATE TABLE lm.exaggeration (
    building_id       bigint PRIMARY KEY REFERENCES lm.building (building_id) ON DELETE CASCADE,
    role              smallint NOT NULL CHECK (role IN (1, 2)),
    landmark_id       bigint NOT NULL,
    scale_from_m      real NOT NULL,
    scale_step        real NOT NULL,
    max_scale         real NOT NULL,
    landmark_centroid geometry(Point) NOT NULL,
    landmark_radius_m real NOT NULL,
    gap_m             double precision NOT NULL,
    centroid          geometry(Point) NOT NULL
);
COMMENT ON TABLE lm.exaggeration IS 'lm.exaggeration_role of every building that has one (the landmarks, and the buildings a landmark''s footprint circle would cover at its top scale); no row for the others. Filled by the landmarks stage (lm.fill_exaggeration) with lm.building; api.export_features and api.export_digest read it.';
COMMENT ON COLUMN lm.exaggeration.role IS '1 a landmark, 2 a building landmark_id''s scaled footprint circle would cover.';
COMMENT ON COLUMN lm.exaggeration.landmark_id IS 'lm.building.building_id of the landmark (itself for role 1).';
COMMENT ON COLUMN lm.exaggeration.gap_m IS 'Centre distance minus both radii at scale 1 (0 for a landmark; negative when the circles overlap).';
