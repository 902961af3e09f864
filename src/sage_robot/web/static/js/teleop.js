// Operator teleop: camera, driving, e-stop, live map, places, events.
import { $, api, batteryText, checkLogin, el, LiveSocket } from "./common.js";
import { Drive } from "./drive.js";
import { LiveMap } from "./livemap.js";
import { loadPlaces as fetchPlaces } from "./places.js";

const CONFIRM_WINDOW_MS = 5000; // the "confirm release" button stays this long
const MAX_EVENTS = 200;
const PLACES_RELOAD_MS = 500; // navigation re-reads the waypoints file on places_changed first

// ---------------------------------------------------------------- control link
let estop = false;
const teleop = new LiveSocket("/ws/teleop", {
  onState: (up) => {
    $("link").classList.toggle("up", up);
    $("link").setAttribute("aria-label", `control link: ${up ? "up" : "down"}`);
    announce(up ? "control link up" : "control link down");
    if (!up) checkLogin();
  },
  onMessage: (msg) => {
    if (msg.type === "estop") showEstop(msg.engaged);
    else if (msg.type === "error") $("teleop-error").textContent = msg.error;
    else if (msg.type === "deadman") logEvent("teleop", msg.message);
  },
});
/** Say it to screen readers (a polite live region; only changes, not every update). */
let lastAnnounced = "";
function announce(text) {
  if (text === lastAnnounced) return;
  lastAnnounced = text;
  $("announce").textContent = text;
}

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
  $("reverse").setAttribute("aria-pressed", String(drive.reverse));
});
$("speed").addEventListener("input", () => {
  drive.maxSpeed = Number($("speed").value);
  $("speed-value").textContent = drive.maxSpeed.toFixed(2);
});

function showEstop(engaged) {
  if (engaged !== estop) announce(engaged ? "E-stop engaged: the robot will not move" : "E-stop released");
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
// Two explicit tools: "go here" (click: drive there facing the way from the robot; drag:
// drive there facing the drag's direction) and "set pose" (press at the robot, drag along its
// heading, then confirm): a drag never resets localization by itself.
async function goTo(body, label) {
  const { ok, data } = await api("/api/goal", body);
  $("goal-msg").textContent = ok ? `going to ${label}` : data.error;
}
const deg = (theta) => `${Math.round((theta * 180) / Math.PI)}°`;
const at = (x, y) => `(${x.toFixed(1)}, ${y.toFixed(1)})`;
const tool = () => document.querySelector("input[name=tool]:checked").value;
let robotPose = null;
let pendingPose = null;

function goHere(x, y, theta) {
  if (theta == null) { // a click: face the way the robot drives there
    theta = robotPose ? Math.atan2(y - robotPose.y, x - robotPose.x) : 0;
  }
  goTo({ x, y, theta }, `${at(x, y)} facing ${deg(theta)}`);
}
function askPose(x, y, theta) {
  pendingPose = { x, y, theta };
  map.setPending(pendingPose);
  $("pose-text").textContent = `${at(x, y)} facing ${deg(theta)}`;
  $("pose-confirm").hidden = false;
  $("pose-yes").focus();
}
function clearPose() {
  pendingPose = null;
  map.setPending(null);
  $("pose-confirm").hidden = true;
}
const map = new LiveMap($("map"), {
  onClick: (x, y) => {
    if (tool() === "goal") goHere(x, y, null);
    else askPose(x, y, robotPose ? robotPose.theta : 0);
  },
  onDrag: (x, y, theta) => (tool() === "goal" ? goHere(x, y, theta) : askPose(x, y, theta)),
});
for (const input of document.querySelectorAll("input[name=tool]")) {
  input.addEventListener("change", () => {
    map.dragColor = tool() === "goal" ? "#3fb950" : "#f2b705";
    map.panMode = tool() === "pan";
    $("map").style.cursor = map.panMode ? "move" : "crosshair";
    if (tool() !== "pose") clearPose();
  });
}
$("zoom-in").addEventListener("click", () => map.zoomBy(1.5));
$("zoom-out").addEventListener("click", () => map.zoomBy(1 / 1.5));
$("zoom-fit").addEventListener("click", () => {
  map.fit();
  $("follow").checked = false;
});
$("follow").addEventListener("change", () => map.setFollow($("follow").checked));
$("costmap-on").addEventListener("change", () => {
  map.setCostmap($("costmap-on").checked);
  for (const key of document.querySelectorAll(".costmap-key")) key.hidden = !$("costmap-on").checked;
});
$("pose-yes").addEventListener("click", async () => {
  const pose = pendingPose;
  clearPose();
  if (!pose) return;
  const { ok, data } = await api("/api/initial_pose", pose);
  $("goal-msg").textContent = ok ? `pose set to ${at(pose.x, pose.y)} facing ${deg(pose.theta)}` : data.error;
});
window.addEventListener("keydown", (e) => {
  if (e.key === "Escape" && pendingPose) $("pose-no").click();
});
$("pose-no").addEventListener("click", () => {
  clearPose();
  $("goal-msg").textContent = "pose not changed";
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
      case "pose":
        robotPose = msg;
        break;
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
  const title = placeTitle(msg.place);
  const parts = [msg.place ? `${state} → ${title}` : state];
  if (!msg.done && msg.distance_remaining_m > 0) {
    parts.push(`${msg.distance_remaining_m.toFixed(1)} m left`);
    if (msg.eta_s) parts.push(`ETA ${formatEta(msg.eta_s)}`);
  }
  if (msg.done && msg.reason && msg.reason !== msg.state) parts.push(msg.reason);
  const text = parts.join(" · ");
  $("nav").textContent = text;
  $("nav").dataset.state = msg.state;
  $("nav").title = msg.place || "";
  const key = `${msg.state} ${msg.place}`;
  if (key !== lastNav && msg.state !== "idle") logEvent("navigation", msg.done ? text : `${state} ${title}`);
  if (key !== lastNav) announce(`navigation: ${msg.place ? `${state} → ${title}` : state}`);
  lastNav = key;
}
function formatEta(s) {
  const m = Math.floor(s / 60);
  return m ? `${m} min ${Math.round(s % 60)} s` : `${Math.round(s)} s`;
}

let titles = new Map(); // code name -> human title
const placeTitle = (name) => titles.get(name) || name || "";

async function loadPlaces() {
  const places = await fetchPlaces();
  const box = $("places");
  box.replaceChildren();
  if (!places) return;
  titles = new Map(places.map((p) => [p.name, p.title]));
  map.setPlaces(places);
  for (const p of places) {
    const tip = `${p.name}${p.description ? ` — ${p.description}` : ""}`;
    box.append(el("button", { title: tip, "data-place": p.name, onclick: () => goTo({ place: p.name }, p.title) }, p.title));
  }
}
$("cancel").addEventListener("click", async () => {
  await api("/api/cancel", {});
  $("goal-msg").textContent = "navigation cancelled";
});
loadPlaces();
