// Visitors' push-to-talk: hold the button (MediaRecorder WebM) or type; show and play the reply.
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

// ---------------------------------------------------------------- hold to talk
let recorder = null;
let chunks = [];
let started = 0;
let holding = false;

async function startRecording() {
  if (recorder) return;
  if (!navigator.mediaDevices || !window.MediaRecorder) {
    setState("error", "this browser cannot record here (it needs https or localhost); type instead");
    return;
  }
  try {
    const stream = await navigator.mediaDevices.getUserMedia({ audio: true });
    const type = RECORDING_TYPES.find((t) => MediaRecorder.isTypeSupported(t));
    recorder = new MediaRecorder(stream, type ? { mimeType: type } : {});
  } catch (err) {
    setState("error", `no microphone: ${err.message || err}`);
    recorder = null;
    return;
  }
  chunks = [];
  started = performance.now();
  if (!holding) started -= MIN_RECORDING_MS; // released while the microphone was opening
  recorder.ondataavailable = (e) => e.data.size && chunks.push(e.data);
  recorder.onstop = () => upload(recorder.stream, recorder.mimeType);
  recorder.start();
  if (!holding) {
    recorder.stop();
    return;
  }
  $("ptt").classList.add("recording");
  $("ptt").textContent = "Listening… release to send";
}

function stopRecording() {
  holding = false;
  if (!recorder || recorder.state !== "recording") return;
  recorder.stop();
}

async function upload(stream, mimeType) {
  stream.getTracks().forEach((t) => t.stop());
  const long = performance.now() - started >= MIN_RECORDING_MS;
  recorder = null;
  $("ptt").classList.remove("recording");
  $("ptt").textContent = "Hold to talk";
  if (!long) {
    setState("error", "hold the button while you speak");
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

if (micAvailable()) document.body.dataset.mic = "available";
else noMicrophone();

ptt.addEventListener("pointerdown", (e) => {
  e.preventDefault();
  holding = true;
  startRecording();
});
for (const ev of ["pointerup", "pointerleave", "pointercancel"]) ptt.addEventListener(ev, stopRecording);
ptt.addEventListener("contextmenu", (e) => e.preventDefault());
