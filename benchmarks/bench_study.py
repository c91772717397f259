"""Where a study run's time goes (issue 54; docs/report.md, "Where the time goes"): each section's wall
and CPU time by stage (``histostudy.core.STAGES``: render, segment, orient, pose, calibrate,
statistics, report), the time outside every stage ("other") and the total, as ``run.json`` records them.

Either reads an output folder that ``histostudy reproduce`` wrote (``--run DIR``: a published run such
as ``docs/results/standard``, or your own), or first runs ``histostudy reproduce --profile P [--only
NN ...] --output DIR`` on this machine (``--profile``; default output: a new temporary folder, so that
no section is kept from an earlier run) and reads what it wrote. A section whose entry in ``run.json``
lacks its stages takes them from its ``results.json`` where that has them (a run made before
``run.json`` copied them); a run of a version that recorded none prints "n/a".

Prints the machine the run's figures come from (CPU model, cores, ISA flags, as ``run.json``
records it) and this one (``histostudy.core.machine_summary``), then the table: a row per section and
one for all, a column per stage that any section entered, each cell "wall / CPU" (in s, min or h,
by the longest section), and the calls per stage. Asserts nothing.

Usage: ``python benchmarks/bench_study.py --run docs/results/standard`` or
``python benchmarks/bench_study.py --profile smoke [--only 01 02] [--output DIR] [--workers N]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from histostudy.core import STAGES, machine_summary
from histostudy.reporting.headline import stage_table
from histostudy.reporting.pipeline import section_stages


def reproduce(profile: str, only: list[str] | None, output: Path, workers: int) -> int:
    """``histostudy reproduce`` into ``output``; its exit status."""
    from histostudy.cli import main as histostudy

    argv = ["reproduce", "--profile", profile, "--output", str(output), "--no-progress", "--workers", str(workers)]
    return histostudy(argv + (["--only", *only] if only else []))


def load_run(folder: Path) -> dict:
    """``run.json`` of ``folder``, each finished section's stages filled in from its ``results.json``
    where ``run.json`` lacks them."""
    run = json.loads((folder / "run.json").read_text(encoding="utf-8"))
    for entry in run.get("notebooks", []):
        if "stages" not in entry and entry.get("status") == "ok" and isinstance(entry.get("seconds"), (int, float)):
            entry.update(section_stages(folder / entry["name"], entry["seconds"], entry.get("cpu_seconds")))
    return run


def recorded_machine(run: dict) -> str:
    machine = (run.get("provenance") or {}).get("machine") or {}
    if not machine:
        return "not recorded"
    flags = " ".join(f"{name}={'yes' if on else 'no'}" for name, on in (machine.get("isa_flags") or {}).items())
    restriction = " ".join(f"{k}={v}" for k, v in (machine.get("isa_restriction") or {}).items()) or "none"
    return (f"{machine.get('cpu_model', 'unknown CPU')}, {machine.get('cpus')} cores; {flags}; "
            f"ISA restriction: {restriction}")


def text_table(header: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(str(row[i])) for row in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(row, widths)))
             for row in [header, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def calls_line(run: dict) -> str:
    calls = {s: 0 for s in STAGES}
    for entry in run.get("notebooks", []):
        for name, totals in (entry.get("stages") or {}).items():
            calls[name] = calls.get(name, 0) + int(totals.get("calls", 0))
    return ", ".join(f"{name} {n:,}" for name, n in calls.items() if n)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--run", type=Path, metavar="DIR", help="an output folder of histostudy reproduce")
    source.add_argument("--profile", help="run histostudy reproduce with this profile first (smoke, standard, paper "
                                          "or a TOML file)")
    parser.add_argument("--only", nargs="+", metavar="NN", help="with --profile: these notebooks only")
    parser.add_argument("--output", type=Path, default=None,
                        help="with --profile: the output folder (default: a new temporary folder)")
    parser.add_argument("--workers", type=int, default=1, help="with --profile: notebooks at once (default 1; "
                                                              "above 1 the sections' CPU time is not known)")
    args = parser.parse_args()
    if args.run is not None and (args.only or args.output is not None):
        parser.error("--only and --output go with --profile")
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")

    folder, status = args.run, 0
    if folder is None:
        folder = args.output or Path(tempfile.mkdtemp(prefix="bench-study-"))
        print(f"histostudy reproduce --profile {args.profile} into {folder}", flush=True)
        status = reproduce(args.profile, args.only, folder, args.workers)
    if not (folder / "run.json").is_file():
        parser.exit(status or 2, f"{folder}: no run.json (not an output folder of histostudy reproduce)\n")
    run = load_run(folder)
    print(f"run: {folder}, profile {run.get('profile')}, commit {(run.get('provenance') or {}).get('git_commit')}")
    print(f"the run's machine: {recorded_machine(run)}")
    print("this machine:\n  " + machine_summary().replace("\n", "\n  "))
    table = stage_table(run)
    if table is None:
        print("no section of this run recorded its stages (a run made before they were recorded)")
    else:
        header, rows, unit = table
        print(f"\ntime by stage, wall / CPU in {unit} (a stage's time adds up the processes that ran it, a "
              f"sweep's workers included; other: the section's time outside every stage):\n")
        print(text_table(header, rows))
        print(f"\ncalls: {calls_line(run) or 'none'}")
    raise SystemExit(status)


if __name__ == "__main__":
    main()
