"""``VoiceNode``: the voice pipeline and the DOA broadcast as one node.

Source of audio (``voice.source``): ``auto`` uses the simulated microphone and speaker on a
simulated clock, the real ones (PortAudio) otherwise. Models load in a worker thread.
Without the voice extras the node still runs: it publishes the DOA and a face state whose
``error_msg`` says what to install.

Topics: publishes ``/sage/ui_state``, ``/doa`` (~12.5 Hz), ``/sage/heard``,
``/sage/audio_out``, ``/sage/voice/latency``; subscribes ``/sage/say``; in simulation
also ``/sim/speaker`` (sim.SpeakerBearing: the nearest person), ``/sim/visitor_say`` (Text
a simulated visitor says into the microphone, rendered with the robot's TTS) and
``/sim/visitor_audio`` (AudioChunk: recorded audio, e.g. a WAV file, into the microphone).
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from sage_robot.core.audio import SAMPLE_RATE_HZ
from sage_robot.core.clock import Clock
from sage_robot.core.config.areas import VoiceSettings
from sage_robot.core.errors import ConfigError, DeviceNotConnectedError
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.sim import SpeakerBearing
from sage_robot.core.msgs.voice import AudioChunk, Doa, Phase, UiState
from sage_robot.core.node import Node
from sage_robot.core.resources import ResourceKey
from sage_robot.core.topics import DOA, SIM_SPEAKER, SIM_VISITOR_AUDIO, SIM_VISITOR_SAY, UI_STATE
from sage_robot.hardware.doa import FRONT_DEG, XVF3800Doa
from sage_robot.voice.audio_io import resample
from sage_robot.voice.partial import PartialTranscriber
from sage_robot.voice.pipeline import VoicePipeline
from sage_robot.voice.player import Mouth
from sage_robot.voice.stt import SpeechToText
from sage_robot.voice.tts import Speech, make_engine
from sage_robot.voice.vad import SileroVad
from sage_robot.voice.wake import OpenWakeWordEngine, WakeDetector
from sage_robot.voice.wake_head import load_head

if TYPE_CHECKING:
    from sage_robot.sim.audio import SimMicrophone, SimSpeaker

T = TypeVar("T")
# On the simulated clock the models load as a lockstep job that lands at this simulated time
# after the node starts (the world steps on beside it, then waits for it if need be), so the
# voice comes up at the same simulated moment on every run, whatever the machine's load. Long
# enough that a real-time `sage sim` does not stand still while they load (5-15 s here).
MODEL_LOAD_SIM_S = 10.0

# Where the simulated speaker writes WAV files (optional)
SIM_OUT_DIR_KEY: ResourceKey[str | Path] = ResourceKey("voice_sim_out_dir")
# The simulated microphone and speaker, once set up
SIM_AUDIO_KEY: ResourceKey[tuple[SimMicrophone, SimSpeaker]] = ResourceKey("voice_sim_audio", tuple)


@dataclass
class VoiceModels:
    """Everything heavy, loaded once: wake engines (microphone and self-hearing), VAD, STT, TTS,
    and with ``asr_partial`` a second Whisper for the partial transcripts (in a low-priority
    child process, see :mod:`partial`: it never holds the final transcription's model or CPU)."""

    wake: OpenWakeWordEngine
    wake_self: OpenWakeWordEngine
    vad: SileroVad
    stt: SpeechToText
    speech: Speech
    stt_partial: PartialTranscriber | None = None

    @classmethod
    def load(cls, s: VoiceSettings) -> VoiceModels:
        stt = SpeechToText(s.stt_model, s.stt_device, s.stt_compute_type)
        stt.warm_up()
        partial = PartialTranscriber(s.asr_partial_model) if s.asr_partial else None
        return cls(
            wake=OpenWakeWordEngine(s.wake_models),
            wake_self=OpenWakeWordEngine(s.wake_models),
            vad=SileroVad(),
            stt=stt,
            speech=Speech(make_engine(s.tts_engine, s.tts_voice, s.tts_deterministic)),
            stt_partial=partial,
        )


def build_pipeline(
    bus: Any, clock: Clock, s: VoiceSettings, models: VoiceModels, mic: Any, speaker: Any
) -> VoicePipeline:
    """Wire models, microphone and speaker into a pipeline (also used by tests and bench)."""
    models.wake.reset()
    models.wake_self.reset()
    # What the robot says, scored by the same models and heads as the mic (patience 1: eager).
    heads = {m: load_head(h) for m, h in s.wake_heads.items()}
    mouth = Mouth(bus, clock, models.speech, speaker,
                  reference=WakeDetector(models.wake_self, s.wake_threshold, s.wake_refractory_s,
                                         patience=1, model_thresholds=s.wake_model_thresholds,
                                         smoothing=s.wake_smoothing_frames,
                                         model_smoothing=s.wake_model_smoothing, heads=heads,
                                         head_threshold=s.wake_head_threshold,
                                         head_gate=s.wake_head_gate))
    wake = WakeDetector.from_settings(models.wake, s)
    partial = models.stt_partial if s.asr_partial else None
    return VoicePipeline(bus, clock, s, mic, mouth, wake, models.vad, models.stt, partial_stt=partial)


async def in_load_thread(fn: Callable[..., T], *args: Any) -> T:
    """Run ``fn`` (model loading: seconds of native code) in its own thread.

    The thread is *not* a daemon: a process that stops meanwhile (Ctrl-C early, a short
    ``sage sim --duration``) waits at exit for the load to finish, because leaving the
    interpreter while onnxruntime / CTranslate2 are still loading aborts the process
    ("terminate called without an active exception", or a segfault)."""
    loop = asyncio.get_running_loop()
    fut: asyncio.Future[T] = loop.create_future()

    def settle(value: Any, exc: BaseException | None) -> None:
        if fut.done():
            return
        if exc is not None:
            fut.set_exception(exc)
        else:
            fut.set_result(value)

    def work() -> None:
        try:
            value, exc = fn(*args), None
        except BaseException as e:  # handed to the awaiting task
            value, exc = None, e
        with contextlib.suppress(RuntimeError):  # the loop closed: nobody waits any more
            loop.call_soon_threadsafe(settle, value, exc)

    threading.Thread(target=work, name="voice.load", daemon=False).start()
    return await fut


class VoiceNode(Node):
    name = "voice"

    async def setup(self) -> None:
        self.vs: VoiceSettings = self.settings.voice
        self.pipeline: VoicePipeline | None = None
        self.doa_angle = FRONT_DEG
        self.doa_source = "fixed"
        self._xvf: XVF3800Doa | None = None
        self._mic: Any = None
        self._speaker: Any = None
        self.simulated = self.vs.source == "sim" or (
            self.vs.source == "auto" and self.clock.is_simulated
        )
        await self._setup_doa()
        self.every(1.0 / self.vs.doa_hz, self._publish_doa, name="voice.doa")
        if not self.vs.enabled:
            self.log.info("voice disabled in the profile")
            return
        self.spawn(self._start_pipeline(), name="voice.pipeline")

    async def _start_pipeline(self) -> None:
        """Load the models off the loop (seconds), then run the pipeline forever."""
        try:
            if self.clock.is_simulated:
                models = await self.clock.offload(VoiceModels.load, self.vs, latency_s=MODEL_LOAD_SIM_S)
            else:
                models = await in_load_thread(VoiceModels.load, self.vs)
            self._open_audio()
        except (ConfigError, DeviceNotConnectedError) as exc:
            self.log.error("voice pipeline unavailable", error=str(exc))
            self.bus.publish(UI_STATE, UiState(Phase.ERROR, error_msg=f"voice: {exc}"))
            return
        self.models = models
        self.pipeline = build_pipeline(self.bus, self.clock, self.vs, models, self._mic,
                                       self._speaker)  # fmt: skip
        if self.simulated:
            self.subscribe(SIM_VISITOR_SAY, Text, self._visitor_says)
            self.subscribe(SIM_VISITOR_AUDIO, AudioChunk, self._visitor_audio)
        self.log.info("voice ready", source="sim" if self.simulated else "mic",
                      wake=",".join(self.vs.wake_models), tts=self.vs.tts_engine)  # fmt: skip
        await self.pipeline.run()

    def _open_audio(self) -> None:
        if self.simulated:
            from sage_robot.sim.audio import SimMicrophone, SimSpeaker

            self._mic = SimMicrophone(self.clock, seed=self.settings.sim.seed)
            self._speaker = SimSpeaker(self.clock, self._mic, self.ctx.resources.get(SIM_OUT_DIR_KEY))
            self.ctx.resources[SIM_AUDIO_KEY] = (self._mic, self._speaker)
        else:
            from sage_robot.hardware.audio import SoundDeviceMicrophone, SoundDeviceSpeaker

            self._mic = SoundDeviceMicrophone(self.vs.mic_device, self.vs.mic_channel)
            self._speaker = SoundDeviceSpeaker(self.vs.speaker_device)

    async def _setup_doa(self) -> None:
        if self.simulated:
            self.doa_source = "sim"
            self.subscribe(SIM_SPEAKER, SpeakerBearing, self._on_bearing)
            return
        xvf = XVF3800Doa()
        try:
            await self.clock.offload(xvf.open)
            self._xvf, self.doa_source = xvf, xvf.source
        except DeviceNotConnectedError as exc:
            self.log.warning("no DOA device; the face looks straight ahead", reason=str(exc))

    def _on_bearing(self, msg: SpeakerBearing) -> None:
        """The simulator's nearest person (seed convention); nobody near: look ahead."""
        self.doa_angle = msg.angle_deg % 360.0 if msg.present else FRONT_DEG

    async def _publish_doa(self) -> None:
        if self._xvf is not None:
            try:
                self.doa_angle = await self.clock.offload(self._xvf.read_deg)
            except DeviceNotConnectedError as exc:
                self.log.warning("DOA device lost", reason=str(exc))
                self._xvf, self.doa_source, self.doa_angle = None, "fixed", FRONT_DEG
        self.bus.publish(DOA, Doa(self.clock.now(), self.doa_angle, self.doa_source))

    async def _visitor_says(self, msg: Text) -> None:
        """Simulation: render ``msg`` with the robot's TTS and speak it into the sim mic in
        one go, as a visitor says "Hey Jarvis. Where is the cafe?" without waiting for the
        robot (the pipeline finds where the wake phrase ended: no pause is needed)."""
        if not msg.data.strip():
            return
        speech = self.models.speech
        pcm = await self.clock.offload(speech.synthesize, msg.data)
        self._mic.inject(resample(pcm, speech.sample_rate, SAMPLE_RATE_HZ))

    def _visitor_audio(self, msg: AudioChunk) -> None:
        """Simulation: recorded audio (e.g. a WAV file or a browser upload) into the sim mic."""
        if msg.sample_rate <= 0 or len(msg.pcm) % 2:
            self.log.warning("bad visitor audio", sample_rate=msg.sample_rate, size=len(msg.pcm))
            return
        pcm = np.frombuffer(msg.pcm, dtype="<i2").astype(np.int16)
        self._mic.inject(resample(pcm, msg.sample_rate, SAMPLE_RATE_HZ))

    async def teardown(self) -> None:
        for dev in (self._mic, self._speaker, self._xvf):
            if dev is not None:
                dev.close()

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {"doa_source": self.doa_source}
        if self.pipeline is not None:
            out.update(self.pipeline.stats())
        return out
