"""The audio format between the microphone and the speech models, defined once.

Hardware (:mod:`sage_robot.hardware.audio`), the simulator (:mod:`sage_robot.sim.audio`),
voice and the web pages all exchange 16 kHz mono int16, cut into 80 ms frames: the unit
openWakeWord scores and the microphones deliver. Speech synthesis is not bound to it: a
TTS engine reports its own output rate (Piper's voice config, espeak-ng's), and audio is
resampled to :data:`SAMPLE_RATE_HZ` where it goes back into the pipeline.
"""

from __future__ import annotations

from typing import Final

SAMPLE_RATE_HZ: Final = 16_000  # the pipeline's sample rate
FRAME_SAMPLES: Final = 1280  # one microphone / wake-word frame (80 ms at 16 kHz)
FRAME_S: Final = FRAME_SAMPLES / SAMPLE_RATE_HZ  # 0.08 s
