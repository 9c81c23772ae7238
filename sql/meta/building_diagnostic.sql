-- meta.building_diagnostic: every finding about a building in one place, for analysts
-- Rows of meta.diagnostic (the building was kept; something was repaired, defaulted or looks odd) and of
-- osm.reject (the building was dropped), keyed by OSM element. Codes include: outline_reduced_by_parts,
-- min_height_ge_height, pitched_roof_zero_levels, unknown_roof_shape, unit_converted, not_watertight,
-- invalid_tag, geometry_repaired, roof_fallback.
-- Example:
--   SELECT code, count(*) FROM meta.building_diagnostic GROUP BY code ORDER BY count(*) DESC;
CREATE OR REPLACE VIEW meta.building_diagnostic AS
SELECT d.osm_type::text AS osm_type, d.osm_id, b.id AS building_id, d.stage, false AS rejected, d.code, d.detail
FROM meta.diagnostic d
LEFT JOIN osm.building b ON b.osm_type = d.osm_type AND b.osm_id = d.osm_id
UNION ALL
SELECT r.osm_type::text, r.osm_id, b.id, r.stage, true, r.reason, r.detail
FROM osm.reject r
LEFT JOIN osm.building b ON b.osm_type = r.osm_type AND b.osm_id = r.osm_id;
COMMENT ON VIEW meta.building_diagnostic IS
    'One row per finding per building: diagnostics (kept) and rejects (dropped). Example: SELECT code, count(*) FROM meta.building_diagnostic GROUP BY code;';
COMMENT ON COLUMN meta.building_diagnostic.osm_type IS 'W = way, R = relation (meta.diagnostic.osm_type or osm.reject.osm_type, as text).';
COMMENT ON COLUMN meta.building_diagnostic.osm_id IS 'OSM id of the way or relation.';
COMMENT ON COLUMN meta.building_diagnostic.building_id IS 'osm.building.id of the element when osm.building has it (kept, or rejected by a stage after ingest, such as lod); NULL when it has none (ingest rejected it).';
COMMENT ON COLUMN meta.building_diagnostic.stage IS 'Stage that recorded the finding (ingest, lod, ...).';
COMMENT ON COLUMN meta.building_diagnostic.rejected IS 'false: a meta.diagnostic row (the building was kept); true: an osm.reject row (the stage dropped it).';
COMMENT ON COLUMN meta.building_diagnostic.code IS 'Stable code: meta.diagnostic.code (invalid_tag, geometry_repaired, unit_converted, ...) or, for a reject, osm.reject.reason (too_small, invalid_geometry, ...).';
COMMENT ON COLUMN meta.building_diagnostic.detail IS 'Human-readable detail: meta.diagnostic.detail or osm.reject.detail.';
