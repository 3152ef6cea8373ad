"""What the Blender add-on and the backend agree on, in one place both import (no torch, no bpy).

- ``exit_codes``: the exit codes of ``python -m backend`` / ``igs``.
- ``events``: the JSON-lines events the backend writes with ``--events`` and the add-on reads.
- ``ply_header``: PLY headers (parse, check the data size they declare).
- ``layer_ply``: the layer PLY layout (properties, SH counts, the ``igs_*`` header comments) and
  its one validator; ``layer_values`` checks the values read (numpy, which both sides have).
- ``camera_json``: the cameras.json the add-on writes for ``igs render --cameras`` and the
  workspace's transforms.json the add-on reads its cameras from.
- ``light_json``: the lights file the add-on writes for ``igs render --light`` (and ``igs synth
  --lights`` reads and writes).
- ``small_file``: the one reader of small files (JSON, lock records): size-capped, regular files
  only, never blocking on a FIFO.
- ``numbers``: the one check of every number read from a JSON file or the command line (finite,
  in range, whole where whole, small enough to compute with).
- ``workspace_lock``: the lock file a writing command holds in a workspace, and the line naming
  its holder that both sides show.
- ``memory_estimate``: a command's peak memory estimated from the workspace's views, the machine's
  free memory, and the one line over the limit that both sides show.
- ``run_record``: the last run's record in a workspace, and the line saying it was killed.

The backend imports this package as ``igs_contract`` (the add-on runs it with the extension folder
first on PYTHONPATH); the add-on imports it relatively, as part of the extension. Nothing here
imports ``backend`` or ``igs_blender``; only ``layer_values`` imports numpy.
"""
