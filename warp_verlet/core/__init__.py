"""The simulation core: the stage table, the immutable Model, the State, the solver that steps it, the
Simulator that drives frames, and the memory and precision decisions made before anything is built."""
