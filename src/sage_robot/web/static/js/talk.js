// Visitors' push-to-talk: hold the button (pointer, Space or Enter), or tap it to start and tap
// again to send (MediaRecorder WebM/MP4), or type; show and play the reply (announced: the
// conversation is a live region).
import { $, api, el } from "./common.js";

const MIN_RECORDING_MS = 300; // shorter presses are taps, not speech
// What MediaRecorder records, best first: WebM/Opus (Chrome, Firefox, Android), MP4/AAC (Safari,
// every iPhone browser). The robot decodes any of them (ffmpeg).
const RECORDING_TYPES = ["audio/webm;codecs=opus", "audio/webm", "audio/mp4", "audio/ogg;codecs=opus"];
const EXTENSIONS = { "audio/webm": "webm", "audio/mp4": "m4a", "audio/ogg": "ogg" };
const UNREACHABLE = "SAGE could not be reached — check the Wi-Fi connection and try again.";

/** What the page is doing, said in #status: "idle", "thinking" (a question is on its way: from
 * the end of typing or recording to the reply), "error" (it failed; the text says why). */
function setState(state, text = "") {
  const status = $("status");
  status.textContent = state === "thinking" ? "thinking…" : text;
  status.classList.toggle("thinking", state === "thinking");
  status.classList.toggle("error", state === "error");
  document.body.dataset.talk = state;
  $("ask-btn").disabled = state === "thinking";
}

/** One clear line for a failed request (status 0: no answer from the robot at all). */
function failure(status, data) {
  if (status === 0) return UNREACHABLE;
  const why = data.error || `the robot answered with error ${status}`;
  return `Sorry, no answer: ${why}`;
}

async function speak(text) {
  try {
    const resp = await fetch("/api/talk/say", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ text }),
    });
    if (!resp.ok) {
      const data = await resp.json().catch(() => ({}));
      $("status").textContent = data.error ? `(no voice: ${data.error})` : "";
      return;
    }
    const url = URL.createObjectURL(await resp.blob());
    const player = $("player");
    player.src = url;
    await player.play().catch(() => {});
  } catch (err) {
    $("status").textContent = `(no voice: ${err})`;
  }
}

async function answer(result) {
  const { ok, status, data } = result;
  if (!ok) {
    setState("error", failure(status, data));
    return;
  }
  if (data.error) { // understood, but nothing to answer (no words heard)
    setState("error", data.error);
    return;
  }
  const turn = el("div", { class: "turn" }, el("div", { class: "bubble you" }, data.transcript),
    el("div", { class: "bubble sage" }, data.reply));
  $("conversation").prepend(turn); // newest exchange on top, question above its reply
  setState("idle");
  document.body.dataset.replies = String(Number(document.body.dataset.replies || 0) + 1);
  if (data.reply) speak(data.reply);
}

$("ask").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const text = $("question").value.trim();
  if (!text) return;
  $("question").value = "";
  if (!$("robot-mic").hidden && $("robot-mic-on").checked) return sayToRobot(text);
  setState("thinking");
  answer(await api("/api/talk/text", { text }));
});

// ---------------------------------------------------------------- the simulated robot's microphone
// In the simulator the typed words can be spoken into the robot's own (simulated) microphone, so
// the face goes through listening, thinking and speaking as for a visitor standing at the robot.
async function sayToRobot(text) {
  $("status").textContent = "saying it to the robot…";
  const { ok, status, data } = await api("/api/talk/robot_mic", { text });
  if (ok) setState("idle", `said to the robot: “${data.spoken}” — it answers on its face`);
  else setState("error", failure(status, data));
  if (ok) document.body.dataset.saidToRobot = String(Number(document.body.dataset.saidToRobot || 0) + 1);
}

api("/api/talk/robot_mic").then(({ ok, data }) => {
  if (!ok || !data.available) return;
  $("wake").textContent = data.wake;
  $("robot-mic").hidden = false;
});

// ---------------------------------------------------------------- hold to talk, or tap to toggle
// Press and hold (pointer, or Space/Enter on the focused button) records until release. A press
// shorter than TAP_MS (or let go before the microphone opened) is a tap: it keeps recording
// until the next tap (tap-to-toggle, for visitors who cannot hold a button).
const TAP_MS = 300;
const LABELS = { off: "Hold to talk", hold: "Listening… release to send", toggle: "Listening… tap to send" };
let recorder = null;
let chunks = [];
let started = 0;
let mode = "off"; // "off", "hold" (pressed), "toggle" (recording after a tap)
let pressedAt = 0;

function showMode(next) {
  mode = next;
  const button = $("ptt");
  button.textContent = LABELS[next];
  button.classList.toggle("recording", next !== "off" && recorder !== null);
  button.setAttribute("aria-pressed", String(next !== "off"));
  document.body.dataset.ptt = next;
}

async function startRecording() {
  if (recorder) return;
  if (!navigator.mediaDevices || !window.MediaRecorder) {
    showMode("off");
    setState("error", "this browser cannot record here (it needs https or localhost); type instead");
    return;
  }
  let stream;
  try {
    stream = await navigator.mediaDevices.getUserMedia({ audio: true });
    const type = RECORDING_TYPES.find((t) => MediaRecorder.isTypeSupported(t));
    recorder = new MediaRecorder(stream, type ? { mimeType: type } : {});
  } catch (err) {
    stream?.getTracks().forEach((t) => t.stop());
    recorder = null;
    showMode("off");
    setState("error", `no microphone: ${err.message || err}`);
    return;
  }
  if (mode === "off") { // tapped twice while the microphone was opening: nothing to send
    stream.getTracks().forEach((t) => t.stop());
    recorder = null;
    return;
  }
  chunks = [];
  started = performance.now();
  recorder.ondataavailable = (e) => e.data.size && chunks.push(e.data);
  recorder.onstop = () => upload(recorder.stream, recorder.mimeType);
  recorder.start();
  showMode(mode);
}

/** A press (pointer down, Space or Enter down): start, or in tap mode, send. */
function press() {
  if (mode === "toggle") return send();
  if (mode === "hold") return;
  pressedAt = performance.now();
  showMode("hold");
  startRecording();
}

/** The press ends: a long hold sends; a tap (or a release before recording) keeps recording. */
function release() {
  if (mode !== "hold") return;
  const tap = performance.now() - pressedAt < TAP_MS || !recorder || recorder.state !== "recording";
  if (tap) showMode("toggle");
  else send();
}

function send() {
  showMode("off");
  if (recorder && recorder.state === "recording") recorder.stop();
}

async function upload(stream, mimeType) {
  stream.getTracks().forEach((t) => t.stop());
  const long = performance.now() - started >= MIN_RECORDING_MS;
  recorder = null;
  showMode("off");
  if (!long) {
    setState("error", "too short: hold the button while you speak, or tap, speak and tap again");
    return;
  }
  const form = new FormData();
  const type = mimeType || "audio/webm";
  form.append("audio", new Blob(chunks, { type }), `speech.${EXTENSIONS[type.split(";")[0]] || "webm"}`);
  setState("thinking");
  let result;
  try {
    const resp = await fetch("/api/talk/audio", { method: "POST", body: form });
    result = { ok: resp.ok, status: resp.status, data: await resp.json().catch(() => ({})) };
  } catch (err) {
    result = { ok: false, status: 0, data: { error: `network: ${err}` } };
  }
  answer(result);
}

const ptt = $("ptt");

// ---------------------------------------------------------------- no microphone here: say so first
// Browsers give a page the microphone only in a secure context (https, or localhost). On the
// robot's plain-http address hold-to-talk cannot work: hide it and point to the https address.
export function micAvailable() {
  return Boolean(window.isSecureContext && navigator.mediaDevices?.getUserMedia && window.MediaRecorder);
}

function noMicrophone() {
  ptt.hidden = true;
  ptt.disabled = true;
  document.body.dataset.mic = "unavailable";
  const note = $("mic-note");
  note.hidden = false;
  const hint = document.querySelector(".hint");
  if (hint) hint.textContent = "Ask about the building, its labs and where things are — or ask me to take you somewhere.";
  if (window.isSecureContext) {
    note.textContent = "This browser cannot record sound here; you can type instead.";
    return;
  }
  note.textContent = "Voice needs a secure https:// address, which this robot does not offer; you can type instead.";
  api("/api/talk_url").then(({ ok, data }) => {
    if (!ok || !data.secure || !data.url) return;
    const secure = new URL(data.url);
    secure.hostname = location.hostname; // the same robot, by the name this phone already uses
    const link = el("a", { href: secure.href }, secure.href);
    note.replaceChildren("Voice needs the secure address ", link, "; you can type instead.");
  });
}

// The microphone blocked for this site (the visitor said no once, or a policy): said before any
// press as well, and undone when it is allowed again (the Permissions API tells the page).
const BLOCKED = "This browser blocks the microphone for this page: allow it in the site settings "
  + "(the icon by the address) to talk; you can type instead.";

function micBlocked(blocked) {
  ptt.hidden = blocked;
  ptt.disabled = blocked;
  document.body.dataset.mic = blocked ? "blocked" : "available";
  $("mic-note").hidden = !blocked;
  $("mic-note").textContent = blocked ? BLOCKED : "";
}

async function watchPermission() {
  if (!navigator.permissions?.query) return; // the press will tell
  try {
    const status = await navigator.permissions.query({ name: "microphone" });
    micBlocked(status.state === "denied");
    status.onchange = () => micBlocked(status.state === "denied");
  } catch {
    // this browser cannot be asked about the microphone: the press will tell
  }
}

if (micAvailable()) {
  document.body.dataset.mic = "available";
  watchPermission();
} else {
  noMicrophone();
}

ptt.addEventListener("pointerdown", (e) => {
  e.preventDefault();
  press();
});
ptt.addEventListener("pointerup", release);
for (const ev of ["pointerleave", "pointercancel"]) ptt.addEventListener(ev, () => mode === "hold" && send());
ptt.addEventListener("contextmenu", (e) => e.preventDefault());
const PRESS_KEYS = new Set([" ", "Enter"]);
ptt.addEventListener("keydown", (e) => {
  if (!PRESS_KEYS.has(e.key)) return;
  e.preventDefault(); // no click: the key is the press
  if (!e.repeat) press();
});
ptt.addEventListener("keyup", (e) => {
  if (!PRESS_KEYS.has(e.key)) return;
  e.preventDefault();
  release();
});
ptt.addEventListener("blur", () => mode === "hold" && send()); // focus moved away while held
// A click with no pointer or key behind it (a screen reader's activation) is a tap.
ptt.addEventListener("click", (e) => {
  if (e.detail !== 0) return;
  press();
  release();
});
showMode("off");
