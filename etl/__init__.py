"""citylod ETL: OSM -> PostGIS -> LOD meshes -> tiles. ``python -m etl --help`` lists the stages."""
