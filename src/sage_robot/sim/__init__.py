"""The simulated world and devices: firmware model behind a pty, lidar, people, camera."""
