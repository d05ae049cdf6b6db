"""What a report was computed from, so that two reports can be compared: the bags' content
fingerprint and the software and processor that ran the workflow.

The workflow is deterministic: the same bags, settings, library versions and processor give the
same report to the bit (``make discrepancy``'s rate_strength case run twice). Float sums in
numpy/BLAS and torch take processor-specific paths, and PINN training amplifies a difference in
the last digits into figures that move by hundreds of newtons, so a report that differs from
another with the same fingerprint and settings differs by what is recorded here.
"""
from __future__ import annotations

import platform
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

LIBRARIES = ("numpy", "scipy", "scikit-learn", "torch", "numba")


def cpu_model() -> str:
    """The processor's model name (Linux /proc/cpuinfo), or platform.processor(), or '?'."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "?"


def environment() -> dict[str, str]:
    """Python, the numerical libraries' versions and the processor."""
    out = {"python": platform.python_version(), "machine": platform.machine(), "cpu": cpu_model()}
    for name in LIBRARIES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out
