"""Stage generalize: simplified footprints, decimated meshes and aggregated blocks, each error measured, into gen.*."""
