"""Names of the bus's topics, services and actions (ROS names where the seed has them).

One table, so a typo is an import error and a reader sees every channel in one place.
"""

from __future__ import annotations

# Topics
CMD_VEL = "/cmd_vel"  # Twist: velocity command to the base
ODOM = "/odom"  # Odometry: wheel odometry from the MCU
IMU = "/imu/data"  # Imu
BATTERY = "/battery_state"  # BatteryState
SCAN = "/scan"  # LaserScan, in the lidar frame
MAP = "/map"  # OccupancyGrid, latched
AMCL_POSE = "/amcl_pose"  # PoseWithCovariance in the map frame
INITIAL_POSE = "/initialpose"  # PoseWithCovariance: set the localization
PLAN = "/plan"  # Path: the global plan
GOAL_POSE = "/goal_pose"  # PoseStamped: a goal clicked on a map
CAMERA = "/image_raw/compressed"  # CompressedImage (JPEG)
DOA = "/doa"  # voice.Doa: speaker direction
UI_STATE = "/sage/ui_state"  # voice.UiState: what the face shows
EVENTS = "/sage/events"  # Event: arrivals, blocked by people, battery, safety stops
SAY = "/sage/say"  # Text: something the robot should say
DIAGNOSTICS = "/diagnostics"  # DiagnosticArray: node health
ESTOP = "/sage/estop"  # EStopState, latched: the operator's latching e-stop
MCU_STATUS = "/mcu/status"  # DiagnosticStatus: serial link state and statistics

# Simulator-only truth (tests and benchmarks read these; nodes above sim never do)
SIM_TRUTH = "/sim/ground_truth"  # Odometry in the map frame
SIM_PEOPLE = "/sim/people"  # sim.People
SIM_COLLISIONS = "/sim/collisions"  # Event per collision

# Actions and services
NAVIGATE_TO = "navigate_to"  # action: nav.NavigateGoal -> nav.NavigateResult
TOUR = "tour"  # action: nav.TourGoal
CANCEL_NAV = "/nav/cancel"  # service
PLACES = "/nav/places"  # service: list of places
NAV_STATE = "/nav/state"  # nav.NavigateFeedback: the navigator's state whoever sent the goal
#   (published on every change and at 1 Hz while a goal runs; IDLE when none)
WHERE_AM_I = "/nav/where_am_i"  # service
KB_SEARCH = "/kb/search"  # service: kb.SearchRequest -> kb.SearchResponse
CONVERSE = "converse"  # action: Text (what the visitor said) -> feedback Text (each sentence
#   to speak, as it streams) -> result Text (the whole reply). Served by the brain.
HEARD = "/sage/heard"  # Text: final transcript of a visitor turn (voice -> anyone)
LOC_HEALTH = "/localization/health"  # nav.LocalizationHealth
AUDIO_OUT = "/sage/audio_out"  # voice.AudioChunk: the robot's speech, for the web pages
TURN_LATENCY = "/sage/voice/latency"  # voice.TurnLatency: per-turn latency breakdown
MAP_ODOM = "/localization/map_odom"  # PoseStamped: pose of the odom frame in the map (map->odom)
GLOBAL_LOCALIZATION = "/localization/global"  # service: Text (any) -> LocalizationHealth; relocalize
CLEAR_COSTMAPS = "/nav/clear_costmaps"  # service: Text (any) -> Text; forget scan obstacles
SIM_VISITOR_SAY = "/sim/visitor_say"  # Text: a simulated visitor speaks it into the sim mic
SIM_VISITOR_AUDIO = "/sim/visitor_audio"  # voice.AudioChunk: recorded audio played into the sim mic
SIM_SPEAKER_BEARING = "/sim/speaker_bearing"  # voice.Doa: simulated visitor's bearing (truth)
SIM_SPEAKER = "/sim/speaker"  # sim.SpeakerBearing: nearest person within 3 m (or none), with distance
