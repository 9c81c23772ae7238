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
