"""Foundations every layer uses, no paper section of their own: the argument checks every
configuration validates through (``checks``), file writes that are atomic and
honour the umask (``io``), the one seeding policy (``seeding``: every random draw takes a seed or a
``numpy.random.Generator``), the provenance recorded beside every result and checkpoint
(``provenance``, with the CPU and its instruction sets from ``machine``), and the Monte-Carlo
sweeps run in this process or on ``dask.distributed`` (``sweeps``, the same numbers either way;
their finished tasks kept on disk by ``sweep_cache``), and the
name of the world frame every position is in (``world_frame``).
See docs/architecture.md, "Seeding and determinism".
"""

from . import checks as _checks
from . import io as _io
from . import machine as _machine
from . import provenance as _provenance
from . import seeding as _seeding
from . import sweep_cache as _sweep_cache
from . import sweeps as _sweeps
from . import world_frame as _world_frame
from .checks import check_count, check_items, check_positive, check_unit_fraction, is_finite_real, is_real
from .io import atomic_path, atomic_write_bytes, atomic_write_json, atomic_write_text, process_umask, to_jsonable
from .machine import (
               AVX2_RESTRICTION,
               BENCHMARK_ISAS,
               ISA_FLAGS,
               ISA_RESTRICTION_ENV,
               avx2_env_words,
               avx2_restriction,
               cpu_model,
               isa_flags,
               isa_restriction,
               machine_summary,
               run_restricted_to,
)
from .provenance import git_commit, package_versions, provenance
from .seeding import as_generator
from .sweep_cache import SWEEP_CACHE_ENV, SweepCache, files_digest, package_digest, resolve_sweep_cache
from .sweeps import SCHEDULER_ENV, SweepExecutor, SweepTaskError, resolve_executor, run_sweep
from .world_frame import WORLD_FRAME, world_frame_keys

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_checks.__all__, *_io.__all__, *_machine.__all__, *_provenance.__all__, *_seeding.__all__, *_sweep_cache.__all__, *_sweeps.__all__,
                              *_world_frame.__all__]))
