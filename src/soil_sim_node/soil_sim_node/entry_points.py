"""Console entry points of soil_sim_node's offline tools (``interrupts.tool_entry``: stops handled from the first instant)."""
from soil_msgs_py.interrupts import tool_entry

soil_plot_episode = tool_entry("soil_plot_episode", "soil_sim_node.plot")
soil_sim_batch = tool_entry("soil_sim_batch", "soil_sim_node.batch")
soil_sim_report = tool_entry("soil_sim_report", "soil_sim_node.report")
