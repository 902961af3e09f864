"""RPLIDAR A1 (the seed robot's lidar): serial protocol, driver and node."""
