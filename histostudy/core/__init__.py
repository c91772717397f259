"""Foundations every layer uses, with no paper section of their own: the argument checks
(``checks``), atomic file writes (``io``), the seeding policy (``seeding``), provenance and the CPU
it ran on (``provenance``, ``machine``), Monte-Carlo sweeps in this process or on dask
(``sweeps``, their finished tasks kept by ``sweep_cache``), results computed once within a scope
(``memo``), the time of a run by stage (``stage_profile``), the world frame's name
(``world_frame``) and where the shipped networks and notebooks are (``shipped``). See
docs/architecture.md, "Seeding and determinism".
"""

from .checks import check_count, check_items, check_positive, check_unit_fraction, is_finite_real, is_real
from .io import atomic_path, atomic_write_json, atomic_write_text, to_jsonable
from .machine import BENCHMARK_ISAS, avx2_env_words, avx2_restriction, machine_summary, run_restricted_to
from .memo import GeneratorMemo, MemoScope, value_digest
from .provenance import git_commit, provenance
from .seeding import as_generator
from .shipped import shipped_dir
from .stage_profile import STAGES, cpu_seconds, merge_stage_totals, stage, stage_delta, stage_totals
from .sweep_cache import SWEEP_CACHE_ENV, files_digest, package_digest
from .sweeps import SCHEDULER_ENV, SweepExecutor, SweepTaskError, resolve_executor, run_sweep
from .world_frame import WORLD_FRAME, world_frame_keys

__all__ = [
    # checks
    "check_count", "check_items", "check_positive", "check_unit_fraction", "is_finite_real", "is_real",
    # files, seeds, provenance
    "atomic_path", "atomic_write_json", "atomic_write_text", "to_jsonable", "as_generator", "git_commit",
    "provenance", "shipped_dir",
    # the CPU
    "BENCHMARK_ISAS", "avx2_env_words", "avx2_restriction", "machine_summary", "run_restricted_to",
    # sweeps
    "SweepExecutor", "SweepTaskError", "resolve_executor", "run_sweep", "SCHEDULER_ENV", "SWEEP_CACHE_ENV",
    "files_digest", "package_digest",
    # results computed once within a scope
    "GeneratorMemo", "MemoScope", "value_digest",
    # the time of a run by stage
    "STAGES", "stage", "stage_totals", "stage_delta", "merge_stage_totals", "cpu_seconds",
    # frames
    "WORLD_FRAME", "world_frame_keys",
]
