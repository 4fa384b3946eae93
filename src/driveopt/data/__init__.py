"""Expert demonstrations: ``demonstrations`` (the HDF5 format: schema, append, load, fingerprint) and
``collect`` (``driveopt collect``: the expert in closed loop, resumable)."""
