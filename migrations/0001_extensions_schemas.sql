-- 0001: extensions and one schema per pipeline stage.
CREATE EXTENSION IF NOT EXISTS postgis;
CREATE EXTENSION IF NOT EXISTS postgis_sfcgal;

CREATE SCHEMA IF NOT EXISTS meta;
CREATE SCHEMA IF NOT EXISTS osm;
CREATE SCHEMA IF NOT EXISTS lod;
CREATE SCHEMA IF NOT EXISTS gen;
CREATE SCHEMA IF NOT EXISTS lm;
CREATE SCHEMA IF NOT EXISTS tex;
CREATE SCHEMA IF NOT EXISTS tiles;
CREATE SCHEMA IF NOT EXISTS api;

COMMENT ON SCHEMA meta IS 'Bookkeeping: migrations, pipeline runs, the loaded dataset, per-building diagnostics.';
COMMENT ON SCHEMA osm IS 'Stage ingest: OSM buildings and building:parts with Simple 3D Buildings tags, and rejects.';
COMMENT ON SCHEMA lod IS 'Stage lod: 3D meshes per building and level of detail (LOD1 extrusions).';
COMMENT ON SCHEMA gen IS 'Stage generalize: simplified footprints, aggregated blocks, decimated meshes.';
COMMENT ON SCHEMA lm IS 'Stage landmarks: salient buildings and their ranking.';
COMMENT ON SCHEMA tex IS 'Stage textures: procedural textures and atlases.';
COMMENT ON SCHEMA tiles IS 'Stage tiles: the spatial tile hierarchy and the assignment of buildings to tiles.';
COMMENT ON SCHEMA api IS 'Stable functions for analysts and the exporter.';
