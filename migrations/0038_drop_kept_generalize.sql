-- 0038: the generalize stage of an update leaves the rows of the batches and block tiles whose input did not
-- change in gen.footprint, gen.building_mesh and gen.block, and replaces only the others' (as textures does
-- since 0037): nothing is copied aside and back any more, which wrote every generalized row twice per update
-- (83 MB on the benchmark extract).
DROP TABLE gen.kept_footprint, gen.kept_building_mesh, gen.kept_block;
