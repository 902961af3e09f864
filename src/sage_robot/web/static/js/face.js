// The kiosk face, the robot's screen: phase, mouth from tts_viseme, pupils from the DOA angle,
// blinking; when idle an invitation (say the wake word or scan the QR code); captions of every
// turn (the robot's microphone, /talk, typed) and announcement; while guiding a card with the
// destination's title, distance, ETA and a Stop; the battery only when low (or to an operator).
// DOA convention (seed): 0° behind, 90° left, 180° in front, 270° right. The face looks at
// the speaker, so a speaker on the robot's left moves the pupils to the screen's right.
import { $, api, batteryText, el, LiveSocket } from "./common.js";

const PUPIL_MAX_PX = 22; // pupil travel from the eye's centre (SVG units)
const MOUTH_MIN = 5; // mouth half-height closed / fully open (SVG units)
const MOUTH_MAX = 38;
const BLINK_MS = 140;
const BLINK_EVERY_MS = [2500, 6000]; // random interval between blinks
const PHASES = ["idle", "listening", "thinking", "speaking", "navigating", "error"];
const CAPTIONS_SHOWN = 3; // caption lines under the face (the newest at the bottom)
const BATTERY_LOW_PCT = 20; // the battery shows to visitors at or below this
const DONE_SHOWN_MS = 4000; // an ended walk's last word ("Arrived", "Stopped") stays this long
const WHO = { visitor: "You", robot: "SAGE" };

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

let captions = [];

function onState(msg) {
  setPhase(msg.phase);
  setMouth(msg.phase === "speaking" ? msg.tts_viseme : 0);
  $("heard").textContent = msg.asr_final || msg.asr_partial || "";
  $("reply").textContent = msg.llm_tokens || "";
  $("error").textContent = msg.phase === "error" ? msg.error_msg || "" : "";
  showCaptions();
}

// ---------------------------------------------------------------- captions
/** The newest caption lines, less those the running voice turn shows live (#heard, #reply). */
function showCaptions() {
  const live = new Set([$("heard").textContent, $("reply").textContent].filter(Boolean));
  const shown = captions.filter((c) => !live.has(c.text)).slice(-CAPTIONS_SHOWN);
  const log = $("caption-log");
  const have = [...log.children].map((li) => li.dataset.id).join(",");
  if (have === shown.map((c) => String(c.id)).join(",")) return; // unchanged: nothing re-announced
  log.replaceChildren(
    ...shown.map((c, i) => {
      const kind = c.via === "announcement" ? "announcement" : c.who;
      return el("li", { class: `${kind}${i < shown.length - 1 ? " old" : ""}`, "data-id": String(c.id),
        "data-via": c.via || "" }, el("span", { class: "who" }, `${WHO[c.who] || c.who}:`), c.text);
    }),
  );
  document.body.dataset.captions = String(captions.length ? captions[captions.length - 1].id : 0);
}

// ---------------------------------------------------------------- guiding
let doneTimer = null;
// The navigator's social events (issue #20): said on the guide line for a few seconds.
const SOCIAL_SHOWN_MS = 5000;
const SOCIAL_WORDS = {
  slowing_for_people: "Slowing down for people…",
  pulling_over: "Making room for people to pass…",
  passing_group: "Going around the group…",
  blocked_by_people: "Excuse me, may I pass?",
};
let social = null; // { text, until }
function socialText() {
  return social && Date.now() < social.until ? social.text : "";
}
function onSocial(msg) {
  social = { text: SOCIAL_WORDS[msg.kind] || msg.message || "", until: Date.now() + SOCIAL_SHOWN_MS };
  if (!$("guide").hidden && $("guide-stop").hidden === false) $("guide-progress").textContent = social.text;
}

function distanceText(m) {
  if (m === null || m === undefined || !(m > 0)) return ""; // 0 before the plan is known
  return m >= 10 ? `${Math.round(m)} m to go` : `${m.toFixed(1)} m to go`;
}

function etaText(s) {
  if (s === null || s === undefined || !(s > 0)) return "";
  return s >= 90 ? `about ${Math.round(s / 60)} min` : `about ${Math.max(1, Math.round(s))} s`;
}

const NAV_WORDS = {
  planning: "Finding the way…",
  waiting_for_people: "Waiting for people to pass…",
  recovering: "Finding a way around…",
  lost: "I am not sure where I am…",
};
const DONE_WORDS = {
  succeeded: "We are here.", canceled: "Stopped.", preempted: "Going somewhere else.", aborted: "I could not get there.",
};

function onNav(msg) {
  const guide = $("guide");
  clearTimeout(doneTimer);
  if (msg.state === "idle" && !msg.done) return hideGuide();
  const title = msg.title || msg.place || "";
  $("guide-title").textContent = title;
  $("guide-title").title = msg.place || ""; // the code name in the tooltip
  document.body.dataset.navState = msg.state;
  if (msg.done) {
    $("guide-label").textContent = msg.state === "succeeded" ? "Arrived at" : "Was taking you to";
    $("guide-progress").textContent = DONE_WORDS[msg.state] || msg.state;
    $("guide-stop").hidden = true;
    doneTimer = setTimeout(hideGuide, DONE_SHOWN_MS);
  } else {
    $("guide-label").textContent = "Taking you to";
    const parts = [distanceText(msg.distance_remaining_m), etaText(msg.eta_s)].filter(Boolean);
    $("guide-progress").textContent = socialText() || NAV_WORDS[msg.state] || parts.join(" · ") || "On our way…";
    $("guide-stop").hidden = false;
    $("guide-stop").disabled = false;
    $("guide-stop").textContent = "Stop";
  }
  guide.hidden = false;
  document.body.dataset.guiding = "1";
}

function hideGuide() {
  $("guide").hidden = true;
  document.body.dataset.guiding = "0";
  document.body.dataset.navState = "idle";
}

// A visitor may stop their own walk: /api/guide/stop is public and only cancels navigation.
$("guide-stop").addEventListener("click", async () => {
  const stop = $("guide-stop");
  stop.disabled = true;
  stop.textContent = "Stopping…";
  const { ok, data } = await api("/api/guide/stop", {});
  if (!ok) {
    stop.disabled = false;
    stop.textContent = "Stop";
    $("guide-progress").textContent = data.error || "could not stop";
  }
});

// ---------------------------------------------------------------- battery: visitors see it only when low
let operator = false;

/** The battery is low enough to tell a visitor (percent known, at most BATTERY_LOW_PCT, not charging). */
export function batteryLow(msg) {
  const pct = msg?.percentage;
  return pct !== null && pct !== undefined && pct <= BATTERY_LOW_PCT && !msg.is_charging;
}

let lastBattery = null;

function onBattery(msg) {
  lastBattery = msg;
  $("battery").textContent = batteryText(msg);
  const low = batteryLow(msg);
  $("battery").classList.toggle("low", low);
  $("battery-wrap").hidden = !(low || operator);
}

api("/api/whoami").then(({ ok, data }) => {
  operator = Boolean(ok && data.operator);
  if (lastBattery) onBattery(lastBattery); // it may have come first
});

new LiveSocket("/ws/status", {
  onState: (up) => $("link").classList.toggle("up", up),
  onMessage: (msg) => {
    if (msg.type === "ui_state") onState(msg);
    else if (msg.type === "battery") onBattery(msg);
    else if (msg.type === "nav") onNav(msg);
    else if (msg.type === "social") onSocial(msg);
    else if (msg.type === "captions") {
      captions = msg.items || [];
      showCaptions();
    }
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

// ---------------------------------------------------------------- say the wake word or scan
api("/api/talk/robot_mic").then(({ ok, data }) => {
  if (!ok || !data.wake) return;
  $("wake").textContent = data.wake.replace(/\b\w/g, (c) => c.toUpperCase()); // "hey jarvis" -> "Hey Jarvis"
});

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
