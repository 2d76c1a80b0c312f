"""Every Warp kernel of warp-verlet, grouped by simulation stage (installed as ``warp_verlet.kernels``).

- :mod:`.integrate`: Verlet position update and its exact first-step initialisation.
- :mod:`.relax`: distance-stick relaxation, graph-coloured Gauss-Seidel and gather-form Jacobi.

Kernels are pure functions of their arguments; which of them a step launches is decided by
:mod:`warp_verlet.core.simulator`, from the scene.
"""
