"""Navigation: maps, costmaps, localization, planning, control, navigator, SLAM."""
