"""The FMU build's compile helper: cedra.compile (the package's one compile helper, at the bottom of the layers so
that the host libraries of cedra.models use it too), under the name the FMU machinery imports it by."""
from cedra.compile import (CACHE_ENV, CC, CompileError, CompileJob, CompileStats, cache_dir, cached_object,
                           compile_object, compile_objects, compiler_identity, link_library, link_program,
                           object_key, run, run_timed, shared_library, source_key)

__all__ = ["CACHE_ENV", "CC", "CompileError", "CompileJob", "CompileStats", "cache_dir", "cached_object",
           "compile_object", "compile_objects", "compiler_identity", "link_library", "link_program", "object_key",
           "run", "run_timed", "shared_library", "source_key"]
