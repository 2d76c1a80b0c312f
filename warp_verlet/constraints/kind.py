"""What one constraint kind declares about itself (:class:`ConstraintKind`), and the defaults a kind without
keys, checks or data of its own takes (:class:`ConstraintSet`). The kinds import this module; the registry
(``warp_verlet.constraints``) imports the kinds.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from ..launches import BoundStage
    from ..scene_keys import Key, Table


@runtime_checkable
class ConstraintKind(Protocol):
    """What one kind of constraint declares about itself."""

    name: str
    """How ``Simulator.stages()`` and the requirements name it."""

    cloth_keys: tuple["Key", ...]
    """The ``[[cloth]]`` keys it owns; their values reach it as ``ClothSpec.options[key.name]``."""

    def named_vertex_sets(self, options) -> tuple[tuple[str, str, str], ...]:
        """The vertex sets a cloth's ``options`` (as read, before ``check_cloth``) select by name, each
        ("primvar" or "subset", name, the key that names it): a mesh cloth read from USD looks them up when it
        reads the mesh (mesh_scene.load_mesh), and ``check_cloth`` finds each one's vertices in
        ``spec.mesh.mesh.source.named_vertices[(kind, name)]``."""

    def check_cloth(self, spec, table: "Table") -> dict[str, Any] | None:
        """Once a cloth is read (``spec``, a scene.ClothSpec, its mesh loaded), check this kind's options against
        it and resolve them (say, selections to particle indices): the options to replace, or None. A problem
        raises ``table.error``."""

    def count(self, scene) -> int | tuple[int, ...]:
        """Its elements in ``scene`` (a scene.Scene), known before anything is built: a number, or a tuple of
        numbers where its arrays come in several sizes; 0 when the scene does not use it."""

    def needed(self, req) -> bool:
        """Whether a scene with these requirements (a stages.Requirements) runs it."""

    def device_bytes(self, req) -> int:
        """The device bytes it allocates (Model, State and solver scratch): the memory estimate's share."""

    def build(self, model, scene, device) -> Any:
        """Its device data for ``model`` (read by its launches, never written), or None; the Model keeps it as
        ``model.constraints[name]`` and names its arrays for the memory accounting."""

    def bind(self, model, state, solver) -> "BoundStage":
        """Its launches against ``state`` (a State of ``model``, stepped by ``solver``, a VerletSolver): per-substep
        set-up as ``run``, per-substep work that divides over the CPU's threads as ``substep_phases`` (run after
        every set's ``run``, before the first sweep), one sweep as ``phases``."""

    def on_tear(self, model, state, torn: "np.ndarray") -> None:
        """React to the torn set changing (``torn``: per stick in ``model.host_sticks`` order)."""

    def capturable(self, device) -> bool:
        """Whether its launches replay correctly from a captured frame on ``device`` (a Warp device); a frame
        with a kind that does not is stepped launch by launch."""

    reads_positions_before_sweeps: bool
    """Whether its per-substep set-up (``bind``'s ``run``) reads or moves the positions the Verlet step left:
    then nothing of the first sweep may be folded into that step (stages.tethers_in_integrate)."""

    clamps_before_sweeps: bool
    """Whether its per-substep set-up runs the colliders' clamps: then the relaxation places the moving colliders
    for the substep before it (stages.collider_placement)."""


class ConstraintSet:
    """Defaults for a kind that owns no keys, has nothing to check, keeps its data in the Model's core arrays
    (sticks, tethers, levels) and ignores tears."""

    name = ""
    cloth_keys: tuple = ()
    reads_positions_before_sweeps = False
    clamps_before_sweeps = False

    def named_vertex_sets(self, options) -> tuple:
        return ()

    def check_cloth(self, spec, table):
        return None

    def count(self, scene) -> int:
        return 0

    def build(self, model, scene, device):
        return None

    def on_tear(self, model, state, torn) -> None:
        return None

    def capturable(self, device) -> bool:
        return True
