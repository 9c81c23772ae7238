"""citylod exporter: tiles in PostGIS -> 3D Tiles 1.1 (tileset.json + glb), checks, and a viewer server.

Pure modules (no database): geodesy, gltf, tileset, checks. Database side: export. ``python -m exporter``.
"""

__version__ = "0.1.0"
ATTRIBUTION = "© OpenStreetMap contributors (ODbL 1.0)"
