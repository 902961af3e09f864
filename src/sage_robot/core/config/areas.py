"""Settings of the areas above the hardware. Each area extends its own section here.

Paths that are empty mean "the file shipped in the package".
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from sage_robot.core.config.base import Section


class SimSettings(Section):
    world_map: str = Field("", description="The true building's map YAML; empty = nav.map.")
    speed: float | None = Field(1.0, description="Real-time factor; null = as fast as possible.")
    seed: int = Field(7, description="Random seed of the world (people, noise).")
    pedestrians: int = Field(6, ge=0, description="Simulated people walking about.")
    clutter: bool = Field(True, description="Place the building's low benches and carts (world.yaml).")
    lidar_beams: int = Field(360, ge=8, le=4096, description="Simulated lidar beams per revolution.")
    lidar_dropout: float = Field(0.01, ge=0, le=1, description="Chance a beam returns nothing (0..1).")
    camera_hz: float = Field(
        15.0, ge=0, description="Camera frames per second of wall time (0 = no camera)."
    )
    people_model: Literal["auto", "jupedsim", "simple"] = Field(
        "auto", description="Pedestrian model: 'jupedsim' (optional extra 'people'), 'simple' (the "
                              "hand-written walkers) or 'auto' (jupedsim when installed)."
    )
    people_ignore_share: float = Field(
        0.2, ge=0, le=1, description="Share of simulated people who do not step aside when asked (0..1)."
    )


class NavSettings(Section):
    map: str = Field("", description="Map YAML; empty = the shipped default building.")
    waypoints: str = Field("", description="Waypoints YAML; empty = waypoints.yaml beside the map.")
    initial_place: str = Field("DOCKING_STATION", description="Place of the initial pose.")
    inflation_radius_m: float = Field(0.55, gt=0, description="Costmap inflation radius (m).")
    cost_scaling_factor: float = Field(3.0, gt=0, description="Inflation decay rate (1/m).")
    controller_hz: float = Field(20.0, gt=0, description="Controller rate (Hz).")
    lookahead_m: float = Field(1.2, gt=0, description="Pure-pursuit lookahead (m).")
    xy_goal_tolerance_m: float = Field(0.25, gt=0, description="Goal position tolerance (m).")
    yaw_goal_tolerance_rad: float = Field(0.25, gt=0, description="Goal heading tolerance (rad).")
    min_particles: int = Field(500, gt=0, description="AMCL particles, minimum.")
    max_particles: int = Field(2000, gt=0, description="AMCL particles, maximum.")
    use_ekf: bool = Field(False, description="Fuse IMU yaw rate with odometry (EKF).")
    people_wait_s: float = Field(20.0, ge=0, description="Wait for people to step aside (s).")
    keepout_mask: str = Field(
        "", description="Nav2 keepout mask YAML; empty = NAME_keepout.yaml beside the map if any."
    )
    speed_mask: str = Field(
        "", description="Nav2 speed mask YAML (percent of top speed); empty = NAME_speed.yaml if any."
    )
    replan_hz: float = Field(1.0, gt=0, description="Global replanning rate while driving (Hz).")
    local_costmap_m: float = Field(6.0, gt=0, description="Side of the rolling local costmap (m).")
    laser_beams: int = Field(60, gt=0, description="Beams per scan the particle filter uses.")
    refine_pose: bool = Field(
        True, description="Place the whole scan on the map by least squares once the particle cloud "
                          "has converged, and report that pose (cm-level instead of the filter's ~5 cm).")
    health_tolerance_m: float = Field(
        0.15, gt=0, description="A beam fits the map when it ends this close to a wall (m)."
    )
    lost_below: float = Field(
        0.35, ge=0, le=1, description="Localization counts as lost below this health score (0..1)."
    )
    relocalize_timeout_s: float = Field(
        40.0, gt=0, description="Spin and relocalize this long before asking for help (s)."
    )
    seed: int = Field(0, description="Random seed of the particle filter.")


class VoiceSettings(Section):
    """The voice pipeline (wake word, VAD, STT, TTS, DOA). Times in seconds."""

    enabled: bool = Field(True, description="Run the voice pipeline.")
    source: str = Field(
        "auto", description="'auto' (sim mic in simulation, else the real mic), 'mic' or 'sim'."
    )
    wake_models: tuple[str, ...] = Field(
        ("hey_jarvis",),
        description="Bundled names or .onnx paths (several at once; 'alexa' also fires on 'Alex s...').",
    )
    wake_threshold: float = Field(0.6, ge=0, le=1, description="Wake-word score threshold.")
    wake_refractory_s: float = Field(
        2.0, ge=0, description="After a detection, ignore the same model for this long (s)."
    )
    wake_patience_frames: int = Field(
        2, ge=1, description="80 ms frames in a row over the threshold for a detection."
    )
    wake_smoothing_frames: int = Field(
        1, ge=1, description="80 ms frames whose scores are averaged before the threshold."
    )
    wake_model_thresholds: dict[str, float] = Field(
        default_factory=lambda: {"hey_jarvis": 0.25, "alexa": 0.8},
        description="Per-model score thresholds overriding wake_threshold (model name → 0..1).",
    )
    wake_model_patience: dict[str, int] = Field(
        default_factory=lambda: {"hey_jarvis": 1, "alexa": 3},
        description="Per-model patience overriding wake_patience_frames (model name → frames).",
    )
    wake_model_smoothing: dict[str, int] = Field(
        default_factory=lambda: {"hey_jarvis": 5, "alexa": 2},
        description="Per-model smoothing overriding wake_smoothing_frames (model name → frames).",
    )
    wake_heads: dict[str, str] = Field(
        default_factory=lambda: {"hey_jarvis": "hey_jarvis_noise"},
        description="Wake heads (model name → bundled head name or .npz path): small "
        "classifiers on the model's speech embeddings, trained for heavy noise.",
    )
    wake_head_threshold: float = Field(
        0.9, ge=0, le=1, description="Threshold of a head's smoothed score."
    )
    wake_head_gate: float = Field(
        0.02, ge=0, le=1,
        description="A head counts only while its model's own smoothed score is at least this.",
    )
    wake_denoise: bool = Field(
        False,
        description="A further wake path through a stationary-noise suppressor "
        "(about twice the wake CPU; adds nothing beside the heads on the tuning set).",
    )
    wake_denoise_thresholds: dict[str, float] = Field(
        default_factory=lambda: {"hey_jarvis": 0.25},
        description="Thresholds of the denoised path (model name → 0..1); models not named "
        "have no second path.",
    )
    vad_threshold: float = Field(0.6, ge=0, le=1, description="Speech probability threshold.")
    vad_silence_s: float = Field(0.7, gt=0, description="Silence that ends an utterance (s).")
    vad_preroll_s: float = Field(0.4, ge=0, description="Audio kept before speech starts (s).")
    max_utterance_s: float = Field(15.0, gt=0, description="Longest utterance recorded (s).")
    no_speech_timeout_s: float = Field(
        5.0, gt=0, description="After the wake word, give up if nobody speaks for (s)."
    )
    follow_up_s: float = Field(
        4.0, ge=0, description="After a reply, listen this long without a wake word (s)."
    )
    stt_model: str = Field("tiny.en", description="Whisper model: 'tiny.en' (bundled) or a path.")
    stt_device: str = Field("cpu", description="'cpu' or 'cuda'.")
    stt_compute_type: str = Field("int8", description="CTranslate2 compute type.")
    stt_min_confidence: float = Field(
        0.4, ge=0, le=1,
        description="A transcript less sure than this (exp of its mean token log-probability) "
        "is not acted on: the robot says it did not catch that.",
    )
    asr_partial: bool = Field(
        True, description="While listening, re-transcribe the utterance so far for the face."
    )
    asr_partial_interval_s: float = Field(
        1.0, gt=0, description="Audio between partial transcripts (s); a busy tick is skipped."
    )
    asr_partial_model: str = Field(
        "tiny.en", description="Whisper model for partials (its own instance, CPU, one thread)."
    )
    tts_engine: str = Field("piper", description="'piper' (GPL extra) or 'espeak' (espeak-ng).")
    tts_voice: str = Field("en_US-joe-medium", description="Piper voice name or .onnx path.")
    tts_deterministic: bool = Field(False, description="No synthesis noise (tests, benchmarks).")
    mic_device: str = Field("", description="Input device name; empty = default.")
    mic_channel: int = Field(0, ge=0, description="Input channel (the XVF3800's processed beam).")
    speaker_device: str = Field("", description="Output device name; empty = default.")
    brain_timeout_s: float = Field(30.0, gt=0, description="Longest wait for the brain's reply (s).")
    doa_hz: float = Field(12.5, gt=0, description="DOA broadcast rate (Hz).")


class LlmSettings(Section):
    base_url: str = Field("", description="OpenAI-compatible endpoint; empty = offline brain.")
    model: str = Field("gpt-4o-mini", description="Chat model name.")
    api_key_env: str = Field("OPENAI_API_KEY", description="Environment variable with the key.")
    timeout_s: float = Field(20.0, gt=0, description="Request timeout (s).")
    max_history_turns: int = Field(12, gt=0, description="Conversation turns kept.")
    max_tool_rounds: int = Field(4, gt=0, description="Tool rounds per visitor turn.")
    idle_reset_s: float = Field(120.0, gt=0, description="Forget the conversation after (s).")
    max_retries: int = Field(2, ge=0, description="Retries on 429/5xx/connection errors (backoff).")
    temperature: float = Field(0.6, ge=0, le=2, description="Sampling temperature.")
    max_tokens: int = Field(400, gt=0, description="Longest reply per model call (tokens).")
    offline_retry_s: float = Field(
        60.0, ge=0, description="After the endpoint fails, answer offline for this long (s)."
    )
    web_search_url: str = Field("https://api.tavily.com/search", description="Tavily search URL.")
    web_search_key_env: str = Field("TAVILY_API_KEY", description="Variable with the Tavily key.")


class KbSettings(Section):
    backend: Literal["sqlite", "postgres"] = Field("sqlite", description="'sqlite' or 'postgres'.")
    path: str = Field(
        "", description="SQLite file; empty = $SAGE_DATA_DIR or ~/.local/share/sage/kb.sqlite3."
    )
    dsn: str = Field("", description="PostgreSQL DSN; empty with backend postgres = embedded.")
    embedder: str = Field("all-MiniLM-L6-v2", description="Embedding model name.")
    top_k: int = Field(5, gt=0, le=50, description="Passages returned by default.")
    load_corpus: bool = Field(True, description="Ingest the shipped corpus into an empty store.")
    max_document_mb: float = Field(
        20.0, gt=0, description="Largest document file accepted (MB = 2**20 bytes); larger ones fail."
    )
    max_inflated_mb: float = Field(
        50.0, gt=0, description="DOCX (zip): most its members may unpack to together (MB); else a zip bomb."
    )
    max_zip_members: int = Field(2000, gt=0, description="DOCX (zip): most files inside the package.")
    max_zip_ratio: float = Field(
        100.0, gt=1, description="DOCX (zip): highest unpacked/packed size of a member over 1 MB."
    )
    max_chars: int = Field(
        2_000_000, gt=0, description="Most characters of text one document may give (refused, not cut)."
    )


class WebSettings(Section):
    host: str = Field("0.0.0.0", description="Address the web server listens on.")
    port: int = Field(8000, ge=0, lt=65536, description="Port of every page and socket; 0 = any free.")
    deadman_s: float = Field(0.25, gt=0, description="Teleop stops after this silence (s): 2.5 page repeats.")
    allowed_origins: tuple[str, ...] = Field(
        (), description="Extra origins (scheme://host:port) for WebSockets and state-changing requests."
    )
    camera_fps: float = Field(15.0, gt=0, le=60, description="Camera frames/s sent to a page, at most.")
    talk_per_min: float = Field(20.0, gt=0, description="Visitor questions per minute per address.")
    trusted_proxies: tuple[str, ...] = Field(
        (),
        description="Addresses (or CIDR networks) of reverse proxies whose X-Forwarded-For / "
        "X-Forwarded-Proto are believed; empty = none (the socket's peer address counts).",
    )
    tls: Literal["auto", "on", "off"] = Field(
        "auto",
        description="HTTPS on web.port: 'on', 'off', or 'auto' = on unless web.host is loopback "
        "(phones need https for the microphone; localhost is secure already).",
    )
    tls_cert: str = Field(
        "", description="The operator's PEM certificate (chain); empty = one made on first run."
    )
    tls_key: str = Field("", description="Its PEM private key (goes with tls_cert).")
    http_port: int | None = Field(
        8080, ge=0, lt=65536,
        description="With HTTPS: plain-http port that redirects to it (path and query kept); "
        "0 = any free (also when web.port is 0); null = none.",
    )
    public_host: str = Field(
        "", description="Name or address phones use for the robot (talk QR code); empty = its LAN address."
    )

    @field_validator("tls", mode="before")
    @classmethod
    def _yaml_on_off(cls, value: object) -> object:
        """YAML reads a bare on/off as true/false."""
        if isinstance(value, bool):
            return "on" if value else "off"
        return value


class EmailSettings(Section):
    smtp_host: str = Field("", description="SMTP server; empty = no e-mail.")
    smtp_port: int = Field(587, gt=0, lt=65536, description="SMTP port.")
    starttls: bool = Field(True, description="Upgrade with STARTTLS.")
    username: str = Field("", description="SMTP login; the password comes from SAGE_SMTP_PASSWORD.")
    sender: str = Field("sage@localhost", description="From address.")
    recipients: tuple[str, ...] = Field((), description="Who hears about a low battery.")
    min_interval_s: float = Field(900.0, ge=0, description="At most one alert per kind per (s).")


class SlamSettings(Section):
    """Online SLAM (mapping mode). Distances in m, angles in rad, map frame = the first scan's."""

    resolution_m: float = Field(0.05, gt=0, le=1, description="Occupancy map cell size (m).")
    max_range_m: float = Field(30.0, gt=0, description="Laser hits beyond this are ignored (m).")
    keyframe_dist_m: float = Field(0.3, gt=0, description="A new pose-graph keyframe after this travel (m).")
    keyframe_angle_rad: float = Field(0.2, gt=0, description="...or after this much turning (rad).")
    loop_radius_m: float = Field(
        6.0, gt=0, description="Loop-closure candidates lie within this distance of a new keyframe (m)."
    )
    loop_min_travel_m: float = Field(
        12.0, gt=0, description="...and at least this far back along the trajectory (m)."
    )
    loop_min_score: float = Field(
        0.55, ge=0, le=1, description="Mean match likelihood a loop closure needs (0..1)."
    )
    loop_min_inliers: float = Field(
        0.65, ge=0, le=1, description="Fraction of scan points on the map a loop closure needs (0..1)."
    )
    range_noise_fraction: float = Field(
        0.01,
        ge=0,
        le=0.2,
        description="The lidar's range noise, 1 sigma, as a fraction of the range (RPLIDAR A1M8: 0.01); "
        "> 0 uses the settings for such a lidar (docs/slam.md), 0 the engine's (a survey-grade scanner).",
    )
    use_imu: bool = Field(
        True,
        description="Turn the odometry with the gyro's yaw rate while /imu/data is published "
        "(mcu.imu_enabled, `--imu`); the wheels' turns where it is not (docs/slam.md).",
    )
    map_period_s: float = Field(1.0, gt=0, description="Publish the growing /map at most this often (s).")
    map_rebuild_period_s: float = Field(
        5.0,
        gt=0,
        description="Redraw the whole /map from the optimised poses after a loop closure at most this often "
        "(s): a redraw costs ~7 ms of CPU per map scan; saving always redraws.",
    )
    out_dir: str = Field("", description="Where maps are saved; empty = <state dir>/maps.")
