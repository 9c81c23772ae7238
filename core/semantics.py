"""Surface semantic codes, one byte per triangle in lod.building_mesh.semantics (the rows of lod.surface_type,
migration 0006): every mesh builder, the textures stage and the exporter use these names, never the numbers."""

SEM_GROUND, SEM_WALL, SEM_ROOF, SEM_WINDOW, SEM_DOOR = 0, 1, 2, 3, 4
N_SEMANTICS = 5
#: A triangle without a stored semantic (a decimated or generalized mesh): coloured and textured as roof when
#: it faces up, as wall otherwise.
SEM_UNKNOWN = 255
