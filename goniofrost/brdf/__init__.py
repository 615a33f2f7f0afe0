"""BRDF files and pictures: MERL .binary reading and writing, preview spheres."""
