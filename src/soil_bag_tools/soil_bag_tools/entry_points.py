"""Console entry points of soil_bag_tools' offline tool (``interrupts.tool_entry``: stops handled from the first
instant). The recorder and the player are nodes: rclpy's signal handling is theirs."""
from soil_msgs_py.interrupts import tool_entry

soil_bag_repair = tool_entry("soil_bag_repair", "soil_bag_tools.repair")
