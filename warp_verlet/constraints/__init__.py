"""Constraint kinds: what a relaxation sweep projects, one module per kind.

Each kind declares, in its own module, everything the rest of the program needs to know of it (the
:class:`ConstraintKind` protocol): its ``[[cloth]]`` keys (the loader takes them into ``ClothSpec.options``, the
docs' tables are written from them), how many elements a scene gives it before anything is built, the device
bytes it allocates, its device data built from the Model's particles, its launches against a State, and what it
does when sticks tear. :data:`CONSTRAINT_KINDS` lists them in the order a sweep projects them; the stage table
(warp_verlet/core/stages.py) runs the ones a scene needs. A new kind is one module here, one kernel file in
kernels/, and one line in :data:`CONSTRAINT_KINDS`.

Elements on more than two particles are coloured by :func:`warp_verlet.geometry.colouring.colour`, which works for any
number of particles per element and keeps an overflow colour for the few that do not fit.
"""

from __future__ import annotations

from .kind import ConstraintKind, ConstraintSet

__all__ = ["CONSTRAINT_KINDS", "ConstraintKind", "ConstraintSet", "cloth_keys", "kinds"]


def _kinds() -> tuple:
    from .angle_limit import AngleHinges, AngleJoints
    from .line_solve import LineSolves
    from .multilevel import Multilevel
    from .rigid_patches import RigidPatches
    from .self_contact import SelfContact
    from .stick_clusters import StickClusters
    from .sticks import GridSticks, GridTiles, Sticks
    from .tethers import GridTethers, Tethers

    # The multilevel pass first (it measures moves from the Verlet prediction), then the line solves (a substep's
    # set-up only: they carry a correction along whole rows and columns before any sweep), then the long-range
    # tethers, so that every sweep starts from particles within reach of their pins, then the sticks, then the
    # angle limits (on lengths the sticks have just set), then the contacts (after the sticks, so that a sweep's
    # last word on a pair is to keep it apart, the sticks' pull being what brings layers together), and the rigid
    # patches last, so that a sweep ends with each rigid.
    return (Multilevel(), LineSolves(), Tethers(), GridTethers(), Sticks(), StickClusters(), GridSticks(), GridTiles(),
            AngleJoints(), AngleHinges(), SelfContact(), RigidPatches())

CONSTRAINT_KINDS: tuple = _kinds()
"""Every constraint kind, in the order a sweep projects them."""


def kinds() -> tuple:
    """The registered kinds, in sweep order, read at each call: everything that loops over the kinds asks here,
    so that a kind registered later (a test's, a benchmark's) is one assignment to :data:`CONSTRAINT_KINDS`."""
    return CONSTRAINT_KINDS


def cloth_keys() -> tuple:
    """The ``[[cloth]]`` keys of every kind, in registry order."""
    return tuple(key for kind in kinds() for key in kind.cloth_keys)
