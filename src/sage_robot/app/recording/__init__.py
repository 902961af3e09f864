"""Recording (MCAP with ROS 2 schemas), replay, and the Foxglove live view."""
