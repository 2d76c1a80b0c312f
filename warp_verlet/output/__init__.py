"""Output: the cache formats registered by suffix, the USD point cache and override writer, its safe
partial-file handling, the background writer, and the cache reader."""
