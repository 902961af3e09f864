// Operator teleop: camera, driving, e-stop, live map, places, events.
import { $, api, batteryText, checkLogin, el, LiveSocket } from "./common.js";
import { Drive } from "./drive.js";
import { LiveMap } from "./livemap.js";

const CONFIRM_WINDOW_MS = 5000; // the "confirm release" button stays this long
const MAX_EVENTS = 200;
const PLACES_RELOAD_MS = 500; // navigation re-reads the waypoints file on places_changed first

// ---------------------------------------------------------------- control link
let estop = false;
const teleop = new LiveSocket("/ws/teleop", {
  onState: (up) => {
    $("link").classList.toggle("up", up);
    if (!up) checkLogin();
  },
  onMessage: (msg) => {
    if (msg.type === "estop") showEstop(msg.engaged);
    else if (msg.type === "error") $("teleop-error").textContent = msg.error;
    else if (msg.type === "deadman") logEvent("teleop", msg.message);
  },
});
const drive = new Drive(teleop, {
  onCommand: (m) => ($("cmd").textContent = `${m.x.toFixed(2)}, ${m.z.toFixed(2)}`),
});
drive.bindKeys();
drive.bindWheel($("wheel"));
drive.bindPedal($("throttle"), "throttle");
drive.bindPedal($("brake"), "brake");
drive.bindJoystick($("joystick"), $("knob"));
$("reverse").addEventListener("click", () => {
  drive.reverse = !drive.reverse;
  $("reverse").textContent = `R: ${drive.reverse ? "on" : "off"}`;
});
$("speed").addEventListener("input", () => {
  drive.maxSpeed = Number($("speed").value);
  $("speed-value").textContent = drive.maxSpeed.toFixed(2);
});

function showEstop(engaged) {
  estop = engaged;
  document.body.dataset.estop = String(engaged);
  $("estop").classList.toggle("engaged", engaged);
  $("estop-banner").classList.toggle("show", engaged);
  $("confirm-release").hidden = true;
  if (!engaged) $("teleop-error").textContent = "";
}
const engage = () => teleop.send({ type: "estop", engaged: true });
$("estop").addEventListener("click", engage);
window.addEventListener("keydown", (e) => {
  if (e.code === "Space" && !(e.target instanceof HTMLInputElement)) {
    e.preventDefault();
    engage();
  }
});
$("release").addEventListener("click", () => {
  $("confirm-release").hidden = false;
  setTimeout(() => ($("confirm-release").hidden = true), CONFIRM_WINDOW_MS);
});
$("confirm-release").addEventListener("click", () => {
  if (estop) teleop.send({ type: "estop", engaged: false });
});

// ---------------------------------------------------------------- camera
let frameUrl = null;
new LiveSocket("/ws/camera", {
  onBinary: (blob) => {
    const url = URL.createObjectURL(blob);
    $("camera").src = url;
    if (frameUrl) URL.revokeObjectURL(frameUrl);
    frameUrl = url;
    $("camera-note").textContent = "";
  },
});

// ---------------------------------------------------------------- live map and status
async function goTo(body, label) {
  const { ok, data } = await api("/api/goal", body);
  $("goal-msg").textContent = ok ? `going to ${label}` : data.error;
}
const map = new LiveMap($("map"), {
  onClick: (x, y) => goTo({ x, y, theta: 0 }, `(${x.toFixed(1)}, ${y.toFixed(1)})`),
  onDrag: async (x, y, theta) => {
    const { ok, data } = await api("/api/initial_pose", { x, y, theta });
    $("goal-msg").textContent = ok ? `pose set to (${x.toFixed(1)}, ${y.toFixed(1)})` : data.error;
  },
});

window.sageMap = map; // for debugging from the console (and the browser tests)

function logEvent(source, text) {
  const log = $("events");
  log.prepend(el("div", {}, `${new Date().toLocaleTimeString()} ${source}: ${text}`));
  while (log.childElementCount > MAX_EVENTS) log.lastChild.remove();
}

new LiveSocket("/ws/live", {
  onMessage: (msg) => {
    map.update(msg);
    switch (msg.type) {
      case "battery":
        $("battery").textContent = batteryText(msg);
        break;
      case "ui_state":
        $("uistate").textContent = msg.phase;
        break;
      case "odom":
        $("odom").textContent = `${msg.x.toFixed(2)}, ${msg.y.toFixed(2)} m`;
        document.body.dataset.odomX = String(msg.x);
        break;
      case "nav":
        showNav(msg);
        break;
      case "estop":
        showEstop(msg.engaged);
        break;
      case "event":
        logEvent(msg.source, `${msg.kind} ${msg.message}`);
        if (msg.kind === "places_changed") setTimeout(loadPlaces, PLACES_RELOAD_MS);
        break;
    }
  },
});

// Navigation, whoever started it (the operator, a visitor through the brain, a tour).
let lastNav = "";
function showNav(msg) {
  const state = msg.state.replaceAll("_", " ");
  const parts = [msg.place ? `${state} → ${msg.place}` : state];
  if (!msg.done && msg.distance_remaining_m > 0) {
    parts.push(`${msg.distance_remaining_m.toFixed(1)} m left`);
    if (msg.eta_s) parts.push(`ETA ${formatEta(msg.eta_s)}`);
  }
  if (msg.done && msg.reason && msg.reason !== msg.state) parts.push(msg.reason);
  const text = parts.join(" · ");
  $("nav").textContent = text;
  $("nav").dataset.state = msg.state;
  const key = `${msg.state} ${msg.place}`;
  if (key !== lastNav && msg.state !== "idle") logEvent("navigation", msg.done ? text : `${state} ${msg.place || ""}`);
  lastNav = key;
}
function formatEta(s) {
  const m = Math.floor(s / 60);
  return m ? `${m} min ${Math.round(s % 60)} s` : `${Math.round(s)} s`;
}

async function loadPlaces() {
  const { ok, data } = await api("/api/places");
  const box = $("places");
  box.replaceChildren();
  if (!ok) return;
  for (const p of data.places) {
    box.append(el("button", { title: p.description, onclick: () => goTo({ place: p.name }, p.name) }, p.name));
  }
}
$("cancel").addEventListener("click", async () => {
  await api("/api/cancel", {});
  $("goal-msg").textContent = "navigation cancelled";
});
loadPlaces();
