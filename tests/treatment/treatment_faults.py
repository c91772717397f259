"""What the journal's fault tests run in child processes: a treatment on the simulated UR5e whose
therapy system logs every firing to a file (the physical truth the journal is checked against)."""

import os
import time

from treatment_setup import R_CT, robot_zone_and_calibration

from histostudy.treatment import execute_treatment, plan_treatment


def fault_plan(spacing_mm: float = 2.5):
    """The plan, calibration and orientation of the fault tests (461 points at 2.5 mm)."""
    robot, zone, T_base_carm, R_base_tcp = robot_zone_and_calibration()
    return plan_treatment(zone, spacing_mm, pulses_per_point=5, axes=R_CT), T_base_carm, R_base_tcp


def fired_points(fired_log) -> list[int]:
    """Every firing the therapy system logged, in order (a point may appear twice)."""
    try:
        text = open(fired_log).read()
    except FileNotFoundError:
        return []
    return [int(line) for line in text.splitlines() if line.strip()]


def treat(journal_path, fired_log, seed: int, fire_s: float = 0.01, spacing_mm: float = 2.5, policy=None) -> None:
    """Run (or resume) the fault plan. Each firing is appended to ``fired_log`` (written before the
    pulses "take" ``fire_s``). An uncertain point is settled as an operator would, from the therapy
    system's log: skipped if it fired, re-fired if it did not (``policy`` overrides)."""
    plan, T_base_carm, R_base_tcp = fault_plan(spacing_mm)

    def deliver(index, pulses):
        with open(fired_log, "a") as fh:
            fh.write(f"{index}\n")
            fh.flush()
            os.fsync(fh.fileno())
        time.sleep(fire_s)

    def from_the_therapy_log(index):
        return "skip" if index in fired_points(fired_log) else "refire"

    from histostudy.robot import SimulatedUR5e

    execute_treatment(SimulatedUR5e(seed), plan, T_base_carm, R_base_tcp, journal_path, deliver=deliver,
                      on_uncertain=policy or from_the_therapy_log)
