"""Surface semantic codes, one byte per triangle in lod.building_mesh.semantics (the rows of lod.surface_type,
migration 0006): every mesh builder and the exporter use these names, never the numbers."""

SEM_GROUND, SEM_WALL, SEM_ROOF, SEM_WINDOW, SEM_DOOR = 0, 1, 2, 3, 4
N_SEMANTICS = 5
