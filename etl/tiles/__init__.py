"""Stage tiles: the quadtree over the buildings into tiles.*."""
