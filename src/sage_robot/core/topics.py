"""Names of the bus's topics, services and actions (ROS names where the seed has them).

One table, so a typo is an import error and a reader sees every channel in one place. Each
topic is declared once, with the message type it carries (:class:`~sage_robot.core.bus.Topic`):
the type checker holds every publisher and subscriber to it. A latched topic (its last value
kept for late readers) is latched in every process that uses it. Services and actions are names.
"""

from __future__ import annotations

from sage_robot.core.bus import Topic
from sage_robot.core.msgs.clock import SimTime
from sage_robot.core.msgs.nav import LocalizationHealth, NavigateFeedback
from sage_robot.core.msgs.sim import People, SpeakerBearing
from sage_robot.core.msgs.std import (
    BatteryState,
    CompressedImage,
    DiagnosticArray,
    DiagnosticStatus,
    EStopState,
    Event,
    HealthReport,
    Imu,
    LaserScan,
    OccupancyGrid,
    Odometry,
    Path,
    PoseStamped,
    PoseWithCovariance,
    Text,
    Twist,
)
from sage_robot.core.msgs.tour import TourState
from sage_robot.core.msgs.voice import AudioChunk, Doa, TurnLatency, UiState

# Topics
CMD_VEL = Topic("/cmd_vel", Twist)  # velocity command to the base
ODOM = Topic("/odom", Odometry)  # wheel odometry from the MCU
IMU = Topic("/imu/data", Imu)
BATTERY = Topic("/battery_state", BatteryState)
SCAN = Topic("/scan", LaserScan)  # in the lidar frame
MAP = Topic("/map", OccupancyGrid, latched=True)
AMCL_POSE = Topic("/amcl_pose", PoseWithCovariance)  # in the map frame
INITIAL_POSE = Topic("/initialpose", PoseWithCovariance)  # set the localization
PLAN = Topic("/plan", Path)  # the global plan
GOAL_POSE = Topic("/goal_pose", PoseStamped)  # a goal clicked on a map
CAMERA = Topic("/image_raw/compressed", CompressedImage)  # JPEG
DOA = Topic("/doa", Doa)  # speaker direction
UI_STATE = Topic("/sage/ui_state", UiState)  # what the face shows
EVENTS = Topic("/sage/events", Event)  # arrivals, blocked by people, battery, safety stops
SAY = Topic("/sage/say", Text)  # something the robot should say
HEARD = Topic("/sage/heard", Text)  # final transcript of a visitor turn (voice -> anyone)
AUDIO_OUT = Topic("/sage/audio_out", AudioChunk)  # the robot's speech, for the web pages
TURN_LATENCY = Topic("/sage/voice/latency", TurnLatency)  # per-turn latency breakdown
DIAGNOSTICS = Topic("/diagnostics", DiagnosticArray)  # node health, ROS style (levels and strings)
HEALTH = Topic("/sage/health", HealthReport, latched=True)  # the launcher's record of every node
ESTOP = Topic("/sage/estop", EStopState, latched=True)  # the operator's latching e-stop
MCU_STATUS = Topic("/mcu/status", DiagnosticStatus)  # serial link state and statistics
NAV_STATE = Topic("/nav/state", NavigateFeedback, latched=True)  # the navigator's state whoever sent the goal
#   (published on every change and at 1 Hz while a goal runs; IDLE when none)
# the local costmap (1 Hz), the teleop map's layer
COSTMAP = Topic("/nav/costmap", OccupancyGrid, latched=True)
LOC_HEALTH = Topic("/localization/health", LocalizationHealth)
# pose of the odom frame in the map (map->odom); latched: a page that opens places the robot at once
MAP_ODOM = Topic("/localization/map_odom", PoseStamped, latched=True)
TOUR_STATE = Topic("/sage/tour", TourState, latched=True)  # the visitor's tour (brain's tour node)

# Simulator-only truth (tests and benchmarks read these; nodes above sim never do)
SIM_TRUTH = Topic("/sim/ground_truth", Odometry)  # in the map frame
SIM_PEOPLE = Topic("/sim/people", People)
SIM_COLLISIONS = Topic("/sim/collisions", Event)  # one per collision
SIM_VISITOR_SAY = Topic("/sim/visitor_say", Text)  # a simulated visitor speaks it into the sim mic
SIM_VISITOR_AUDIO = Topic("/sim/visitor_audio", AudioChunk)  # recorded audio played into the sim mic
SIM_SPEAKER_BEARING = Topic("/sim/speaker_bearing", Doa)  # simulated visitor's bearing (truth)
SIM_SPEAKER = Topic("/sim/speaker", SpeakerBearing)  # nearest person within 3 m (or none), with distance
CLOCK = Topic("/clock", SimTime)  # the simulator's time, for processes that follow it (use_sim_time)

# Actions and services
NAVIGATE_TO = "navigate_to"  # action: nav.NavigateGoal -> nav.NavigateResult
TOUR = "tour"  # action: nav.TourGoal
CONVERSE = "converse"  # action: Text (what the visitor said) -> feedback Text (each sentence
#   to speak, as it streams) -> result Text (the whole reply). Served by the brain.
CANCEL_NAV = "/nav/cancel"  # service
PLACES = "/nav/places"  # service: list of places
WHERE_AM_I = "/nav/where_am_i"  # service
KB_SEARCH = "/kb/search"  # service: kb.SearchRequest -> kb.SearchResponse
GLOBAL_LOCALIZATION = "/localization/global"  # service: Text (any) -> LocalizationHealth; relocalize
CLEAR_COSTMAPS = "/nav/clear_costmaps"  # service: Text (any) -> Text; forget scan obstacles
TOUR_PLAN = "/sage/tour/plan"  # service: tour.TourRequest -> tour.TourPlan (brain's tour node)
TOUR_CONTROL = "/sage/tour/control"  # service: tour.TourCommand -> tour.TourState (start/pause/...)
