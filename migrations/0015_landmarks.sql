-- 0015: the landmarks stage's table: each building's saliency measures, score, rank and landmark level.
CREATE TABLE lm.building (
    building_id            bigint PRIMARY KEY REFERENCES osm.building (id) ON DELETE CASCADE,
    centroid               geometry(Point) NOT NULL,
    height_m               real NOT NULL,
    volume_m3              double precision NOT NULL,
    area_m2                double precision NOT NULL,
    relative_height        real NOT NULL,
    shape_distinctiveness  real NOT NULL,
    semantic               real NOT NULL,
    score                  real NOT NULL,
    rank                   integer NOT NULL UNIQUE,
    level                  smallint NOT NULL,
    is_landmark            boolean NOT NULL,
    lod2_band              smallint CHECK (lod2_band IS NULL OR is_landmark)
);
CREATE INDEX building_rank_idx ON lm.building (rank);
CREATE INDEX building_landmark_idx ON lm.building (level DESC) WHERE is_landmark;
CREATE INDEX building_centroid_idx ON lm.building USING gist (centroid);
COMMENT ON TABLE lm.building IS 'Saliency of every drawn building (an outline with its parts, or a lone part): the raw measures, the weighted score, its rank and its level in the Winter et al. voting hierarchy. Filled by the landmarks stage; the weights are in the stage''s meta.pipeline_run params.';
COMMENT ON COLUMN lm.building.building_id IS 'osm.building.id of the outline (the group id of tiles.building_tile).';
COMMENT ON COLUMN lm.building.centroid IS 'Point on the outline, working CRS (tiles.grid srid): the node of the Delaunay triangulation.';
COMMENT ON COLUMN lm.building.height_m IS 'Measure: top of the tallest part (m above ground, LOD2 meshes).';
COMMENT ON COLUMN lm.building.volume_m3 IS 'Measure: volume of the LOD2 meshes of the building and its parts (m³).';
COMMENT ON COLUMN lm.building.area_m2 IS 'Measure: footprint area of the outline (m²).';
COMMENT ON COLUMN lm.building.relative_height IS 'Measure: height / mean height of the buildings within lm_neighbour_radius_m (1 with no neighbours).';
COMMENT ON COLUMN lm.building.shape_distinctiveness IS 'Measure: RMS z-score of the footprint''s shape descriptors (compactness, rectangularity, log vertices, log area) against its neighbours'' (0 = typical).';
COMMENT ON COLUMN lm.building.semantic IS 'Measure in [0, 1]: weighted tags (place of worship or religious building type, tower, historic/heritage, wikidata, tourism, name); etl/landmarks/stage.py SEMANTIC.';
COMMENT ON COLUMN lm.building.score IS 'Saliency in [0, 1]: sum of weight × normalized measure / sum of weights (etl.landmarks.saliency.saliency).';
COMMENT ON COLUMN lm.building.rank IS '1 = most salient.';
COMMENT ON COLUMN lm.building.level IS 'Landmark level: voting rounds survived (0 = never promoted); the single most salient building has the highest.';
COMMENT ON COLUMN lm.building.lod2_band IS 'Landmarks only: the coarsest tile band (tiles.tile.gen_level) that draws it at LOD2 instead of a simplified solid, 2 - (level - lowest landmark level): one band coarser per level above the lowest landmark level, and -32768 (every band) for the top of the hierarchy; coarser bands draw its simplified solid, never a block.';
COMMENT ON COLUMN lm.building.is_landmark IS 'Level high enough to be a landmark (at most lm_max_fraction of the buildings): sets osm.building.protected, never aggregated.';
