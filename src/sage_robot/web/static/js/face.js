// The kiosk face: phase, mouth from tts_viseme, pupils from the DOA angle, blinking, captions.
// DOA convention (seed): 0° behind, 90° left, 180° in front, 270° right. The face looks at
// the speaker, so a speaker on the robot's left moves the pupils to the screen's right.
import { $, batteryText, LiveSocket } from "./common.js";

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

lookAt(180);
setMouth(0);
blinkLoop();
document.addEventListener("dblclick", () => document.documentElement.requestFullscreen?.().catch(() => {}));
