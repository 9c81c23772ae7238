"""Stage ingest: OSM buildings, parts and building relations, with their Simple 3D Buildings tags, into osm.*."""
