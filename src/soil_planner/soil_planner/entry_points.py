"""Console entry points of soil_planner's offline tools (``interrupts.tool_entry``: stops handled from the first instant)."""
from soil_msgs_py.interrupts import tool_entry

soil_planner_calibrate = tool_entry("soil_planner_calibrate", "soil_planner.bound_calibration")
