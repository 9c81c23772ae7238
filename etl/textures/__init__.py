"""Stage textures: procedural facades and roofs in multi-resolution atlas pages into tex.*."""
