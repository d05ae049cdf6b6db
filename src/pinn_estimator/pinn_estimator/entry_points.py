"""Console entry points of pinn_estimator's offline tools: each runs its tool's ``main`` through
``interrupts.run_tool``, so Ctrl-C and SIGTERM are handled from the script's first instant, not only
once the tool's module (torch, scipy, matplotlib: up to 2 s) is imported. This module imports nothing
heavy (nor does the package's ``__init__``); ``python -m MODULE`` runs the same ``main`` without it.
"""
from __future__ import annotations

from soil_msgs_py.interrupts import run_tool

TOOLS = {  # console script -> the module whose main(argv) it runs
    "pinn_train": "pinn_estimator.train",
    "pinn_eval": "pinn_estimator.evaluate",
    "pinn_fusion_calibrate": "pinn_estimator.fusion_calibration",
}


def pinn_train(argv=None):
    return run_tool("pinn_train", TOOLS["pinn_train"], argv)


def pinn_eval(argv=None):
    return run_tool("pinn_eval", TOOLS["pinn_eval"], argv)


def pinn_fusion_calibrate(argv=None):
    return run_tool("pinn_fusion_calibrate", TOOLS["pinn_fusion_calibrate"], argv)
