"""Rigid bodies, triangle rasterisation into grid cells, segment/triangle intersection."""
