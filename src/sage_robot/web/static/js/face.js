// The kiosk face: phase, mouth from tts_viseme, pupils from the DOA angle, blinking, captions.
// DOA convention (seed): 0° behind, 90° left, 180° in front, 270° right. The face looks at
// the speaker, so a speaker on the robot's left moves the pupils to the screen's right.
import { $, api, batteryText, LiveSocket } from "./common.js";

const PUPIL_MAX_PX = 22; // pupil travel from the eye's centre (SVG units)
const MOUTH_MIN = 5; // mouth half-height closed / fully open (SVG units)
const MOUTH_MAX = 38;
const BLINK_MS = 140;
const BLINK_EVERY_MS = [2500, 6000]; // random interval between blinks
const PHASES = ["idle", "listening", "thinking", "speaking", "navigating", "error"];

function setPhase(phase) {
  if (!PHASES.includes(phase)) return;
  document.body.dataset.phase = phase;
  $("phase").textContent = phase;
}

function setMouth(viseme) {
  const v = Math.max(0, Math.min(1, Number(viseme) || 0));
  $("mouth").setAttribute("ry", String(MOUTH_MIN + v * (MOUTH_MAX - MOUTH_MIN)));
}

/** Pupil offset (SVG units) for a DOA angle in degrees. */
export function pupilOffset(angleDeg) {
  const rel = ((angleDeg - 180) * Math.PI) / 180; // 0 = straight ahead, -90° = robot's left
  return { x: -Math.sin(rel) * PUPIL_MAX_PX, y: 0 };
}

function lookAt(angleDeg) {
  const { x, y } = pupilOffset(angleDeg);
  for (const id of ["pupil-left", "pupil-right"]) {
    $(id).setAttribute("cx", x.toFixed(1));
    $(id).setAttribute("cy", y.toFixed(1));
  }
  document.body.dataset.pupilX = x.toFixed(1);
}

function blinkLoop() {
  const [lo, hi] = BLINK_EVERY_MS;
  setTimeout(() => {
    $("face").classList.add("blink");
    setTimeout(() => $("face").classList.remove("blink"), BLINK_MS);
    blinkLoop();
  }, lo + Math.random() * (hi - lo));
}

function onState(msg) {
  setPhase(msg.phase);
  setMouth(msg.phase === "speaking" ? msg.tts_viseme : 0);
  $("heard").textContent = msg.asr_final || msg.asr_partial || "";
  $("reply").textContent = msg.llm_tokens || "";
  $("error").textContent = msg.phase === "error" ? msg.error_msg || "" : "";
}

new LiveSocket("/ws/status", {
  onState: (up) => $("link").classList.toggle("up", up),
  onMessage: (msg) => {
    if (msg.type === "ui_state") onState(msg);
    else if (msg.type === "battery") $("battery").textContent = batteryText(msg);
  },
});
new LiveSocket("/ws/doa", { onMessage: (msg) => msg.type === "doa" && lookAt(msg.angle) });

// ---------------------------------------------------------------- the robot's voice (simulation)
// /ws/audio sends binary chunks: uint32 LE sample rate, then int16 LE mono PCM. On the real
// robot the speaker plays them; in simulation this tablet is the speaker.
let audio = null;
let playAt = 0;
let chunks = 0;

function playChunk(buf) {
  if (!audio) audio = new AudioContext();
  const rate = new DataView(buf).getUint32(0, true);
  const pcm = new Int16Array(buf.slice(4));
  if (pcm.length === 0) return;
  const out = audio.createBuffer(1, pcm.length, rate);
  const ch = out.getChannelData(0);
  for (let i = 0; i < pcm.length; i++) ch[i] = pcm[i] / 32768;
  const src = audio.createBufferSource();
  src.buffer = out;
  src.connect(audio.destination);
  playAt = Math.max(playAt, audio.currentTime + 0.05);
  src.start(playAt);
  playAt += out.duration;
  chunks += 1;
  document.body.dataset.audioChunks = String(chunks);
  $("sound").hidden = audio.state === "running";
}

$("sound").addEventListener("click", () => {
  if (!audio) audio = new AudioContext();
  audio.resume().then(() => ($("sound").hidden = true));
});

api("/api/health").then(({ ok, data }) => {
  if (!ok || !data.simulated) return;
  new LiveSocket("/ws/audio", {
    onBinary: async (blob) => playChunk(await blob.arrayBuffer()),
  });
});

// ---------------------------------------------------------------- scan to talk
// The server draws /talk's address (https at the robot's network address) as a QR code.
api("/api/talk_url").then(({ ok, data }) => {
  if (!ok || !data.url) return;
  const img = $("talk-qr-img");
  img.onload = () => ($("talk-qr").hidden = false);
  img.alt = `QR code: ${data.url}`;
  img.src = "/api/talk_qr.svg";
  $("talk-url").textContent = data.url.replace(/^https?:\/\//, "");
  document.body.dataset.talkUrl = data.url;
});

lookAt(180);
setMouth(0);
blinkLoop();
document.addEventListener("dblclick", () => document.documentElement.requestFullscreen?.().catch(() => {}));
