"""Stage landmarks: saliency, the Delaunay voting hierarchy and the exaggeration of landmarks into lm.*."""
