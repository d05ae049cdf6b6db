"""Console entry points of soil_discrepancy's offline tools (``interrupts.tool_entry``: stops handled from the first instant)."""
from soil_msgs_py.interrupts import tool_entry

soil_discrepancy = tool_entry("soil_discrepancy", "soil_discrepancy.cli")
