-- 0013: protected buildings (landmarks) are looked up on their own by api.buildings_for_tile's block bands.
CREATE INDEX building_protected_idx ON osm.building (id) WHERE protected;
