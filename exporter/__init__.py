"""citylod exporter: tiles in PostGIS -> 3D Tiles 1.1 (tileset.json + glb), checks, and a viewer server.

Pure (no database): gltf, content, meshopt, tileset, subtree, stream, checks. Database side: export (the stage),
publish and reuse; serve/ (the server) and viewer/. ``python -m exporter serve | check``. Imports core only.
"""

__version__ = "0.1.0"
ATTRIBUTION = "© OpenStreetMap contributors (ODbL 1.0)"
