"""Small hand-made meshes shared by the faces, writer and preview tests: faces of mixed sizes whose answers
(sides, neighbours, hidden polygons) can be worked out from the picture."""

from __future__ import annotations

import numpy as np

from warp_verlet.geometry.faces import Faces

# A flat "house" of three faces, counter-clockwise seen from +Z:
#
#        3 (0.5, 1.5)
#       / \___
#      4   2---6        face 0: pentagon 0 1 2 3 4
#      |   |   |        face 1: quad     1 5 6 2
#      0---1---5        face 2: triangle 2 6 3  (its last side, 3 -> 2, is the pentagon's 2 -> 3)
HOUSE = Faces([5, 4, 3], [0, 1, 2, 3, 4, 1, 5, 6, 2, 2, 6, 3])
HOUSE_POINTS = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0.5, 1.5, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)],
                        np.float32)
