"""Rigid bodies (analytic shapes and triangle meshes), their signed distances, mesh files,
the Fig. 6 character, triangle rasterisation into grid cells, segment/triangle intersection."""
