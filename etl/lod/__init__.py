"""Stage lod: LOD1 blocks, LOD2 roofs for every roof:shape and LOD3 windows and doors into lod.building_mesh."""
