"""Console entry points of soil_bringup's offline tools (``interrupts.tool_entry``: stops handled from the first instant)."""
from soil_msgs_py.interrupts import tool_entry

soil_cut_report = tool_entry("soil_cut_report", "soil_bringup.cut_report")
soil_demo = tool_entry("soil_demo", "soil_bringup.demo")
soil_launch = tool_entry("soil_launch", "soil_bringup.launch")
