"""Cloth geometry: meshes read and welded, faces, grids and their sticks, and the colouring of sticks
and other constraint elements."""
