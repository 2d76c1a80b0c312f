"""The applications: the command line, running a scene to a cache, sweeps, the live and view pages, and
the preview."""
