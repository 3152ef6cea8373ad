"""The backend's Python environment: the interpreter and pinned requirements (``backend_env``), what it lacks
(``check_env``), its set-up (``setup_env``) and the CUDA kernels' build (``cuda_build``). Imports no bpy;
``check_env``, ``setup_env`` and ``cuda_build`` also run as scripts, by path, in other interpreters."""
