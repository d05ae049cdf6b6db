"""Console entry points of soil_discrepancy's offline tools: each runs its tool's ``main`` through
``interrupts.run_tool``, so Ctrl-C and SIGTERM are handled from the script's first instant, not only
once the tool's module (torch, scipy, matplotlib: up to 2 s) is imported. This module imports nothing
heavy (nor does the package's ``__init__``); ``python -m MODULE`` runs the same ``main`` without it.
"""
from __future__ import annotations

from soil_msgs_py.interrupts import run_tool

TOOLS = {  # console script -> the module whose main(argv) it runs
    "soil_discrepancy": "soil_discrepancy.cli",
}


def soil_discrepancy(argv=None):
    return run_tool("soil_discrepancy", TOOLS["soil_discrepancy"], argv)
