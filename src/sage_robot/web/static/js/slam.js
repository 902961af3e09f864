// SLAM controls. Teleop page: while SLAM runs, its progress and "Save map" (the live map above
// grows as the robot is driven). Admin page: the saved maps, each with "Use as tour map".
// Both pages: "Use as tour map" writes NAME.profile.yaml; the page shows the command that tours it.
import { $, api, el } from "./common.js";

const PROGRESS_MS = 2000; // how often the teleop page asks how mapping is going
const NAME_RE = /^[A-Za-z0-9_-][A-Za-z0-9_.-]*$/; // as the server's check_name

function say(id, ok, text) {
  const msg = $(id);
  if (!msg) return;
  msg.className = ok ? "ok" : "error";
  msg.textContent = text;
}

/** Make the saved map NAME the tour map; report in the element `msgId`. */
export async function useAsTourMap(name, msgId) {
  const { ok, data } = await api("/api/slam/tour-map", { name });
  say(msgId, ok, ok
    ? `${name} is the tour map (${data.places} place${data.places === 1 ? "" : "s"}). Tour it: ${data.command}`
    : data.error);
  return ok;
}

// ---------------------------------------------------------------- teleop: save while mapping
async function showProgress() {
  const { ok, data } = await api("/api/slam/progress");
  const running = ok && data.running;
  $("slam-panel").hidden = !running;
  if (!running) return;
  $("slam-progress").textContent = data.scans === undefined
    ? "mapping: waiting for the first scan…"
    : `mapping: ${data.scans} scans, ${data.keyframes} keyframes, ${data.loop_closures} loops closed, ` +
      `match ${(100 * data.match_score).toFixed(0)} %`;
}

async function saveMap(ev) {
  ev.preventDefault();
  const name = $("slam-name").value.trim();
  if (!NAME_RE.test(name)) {
    say("slam-msg", false, "map name: use letters, digits, '_', '-' and '.' only");
    return;
  }
  $("slam-save-btn").disabled = true;
  say("slam-msg", true, `saving ${name}…`);
  const { ok, data } = await api("/api/slam/save", { name });
  $("slam-save-btn").disabled = false;
  say("slam-msg", ok, ok ? `saved ${data.yaml}` : data.error);
  $("slam-tour").hidden = !ok;
  $("slam-tour").dataset.name = name;
}

function initTeleop() {
  $("slam-save").addEventListener("submit", saveMap);
  $("slam-tour").addEventListener("click", () => useAsTourMap($("slam-tour").dataset.name, "slam-msg"));
  showProgress();
  setInterval(showProgress, PROGRESS_MS);
}

// ---------------------------------------------------------------- admin: saved maps
async function listMaps() {
  const { ok, data } = await api("/api/slam/maps");
  const box = $("saved-maps");
  box.replaceChildren();
  if (!ok) {
    box.append(el("p", { class: "error" }, data.error || "the saved maps cannot be listed"));
    return;
  }
  if (!data.maps.length) {
    box.append(el("p", { class: "muted" }, `No saved maps in ${data.directory} yet: map with sage slam.`));
    return;
  }
  const ul = el("ul", { class: "saved-maps" });
  for (const m of data.maps) {
    const button = el("button", { type: "button", "data-map": m.name }, "Use as tour map");
    button.addEventListener("click", async () => {
      if (await useAsTourMap(m.name, "tourmap-msg")) listMaps();
    });
    ul.append(el("li", { title: m.yaml }, `${m.name} `, m.tour_profile ? el("span", { class: "muted" },
      "(has a tour profile) ") : "", button));
  }
  box.append(ul);
}

if ($("slam-panel")) initTeleop();
if ($("saved-maps")) listMaps();
