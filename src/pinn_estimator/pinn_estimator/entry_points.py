"""Console entry points of pinn_estimator's offline tools (``interrupts.tool_entry``: stops handled from the first instant)."""
from soil_msgs_py.interrupts import tool_entry

pinn_train = tool_entry("pinn_train", "pinn_estimator.train")
pinn_eval = tool_entry("pinn_eval", "pinn_estimator.evaluate")
pinn_fusion_calibrate = tool_entry("pinn_fusion_calibrate", "pinn_estimator.fusion_calibration")
