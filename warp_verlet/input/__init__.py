"""Scene input: a scene file read and checked key by key into the frozen Scene, its meshes loaded, and the
warnings a valid scene deserves."""
