"""What every test session prints first: the CPU, its instruction-set flags, any restriction of the
libraries to a lower instruction set (``make test-avx2``) and the numerical libraries' versions, so
that a failure on one machine can be told from a failure on every machine (docs/testing.md)."""

from histostudy.core.machine import machine_summary


def pytest_report_header(config):
    return machine_summary().splitlines()
