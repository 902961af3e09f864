"""Real device drivers (MCU link, lidar, camera, audio). The simulator implements the same interfaces."""
