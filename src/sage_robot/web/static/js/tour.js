// The visitor's tour on the face and on teleop (the "tour" channel of /ws/status): the planned
// stops with the current one marked, the phase, and the controls. On the face a visitor may end
// the tour (POST /api/tour/stop, public); on teleop the operator pauses, resumes, skips or stops.
// The page includes a #tour section holding #tour-phase, #tour-stops and the buttons it offers
// (#tour-pause, #tour-resume, #tour-skip, #tour-stop): this module only fills what exists.
import { $, api, el, LiveSocket } from "./common.js";

const PHASE_WORDS = {
  driving: "On our way to",
  at_stop: "Here at",
  paused: "Paused — next:",
  done: "Tour finished",
  stopped: "Tour ended",
};
const ACTIVE = ["driving", "at_stop", "paused"];
const ENDED_SHOWN_MS = 6000; // a finished or stopped tour stays on the face this long
let hideTimer = 0;

function stopItem(stop) {
  const mark = { visited: "✓ ", skipped: "↷ ", current: "▶ " }[stop.status] || "";
  return el("li", { class: `tour-stop tour-${stop.status}`, title: stop.name }, mark + stop.title);
}

function show(msg) {
  const box = $("tour");
  if (!box) return;
  const active = ACTIVE.includes(msg.phase);
  const ended = msg.phase === "done" || msg.phase === "stopped";
  clearTimeout(hideTimer);
  box.hidden = !(active || ended);
  if (box.dataset.page === "face") document.body.dataset.tour = box.hidden ? "0" : "1";
  box.dataset.phase = msg.phase;
  if (ended && box.dataset.page === "face") {
    hideTimer = setTimeout(() => {
      box.hidden = true;
      document.body.dataset.tour = "0";
    }, ENDED_SHOWN_MS);
  }
  const where = active && msg.current_title ? ` ${msg.current_title}` : "";
  const minutes = msg.minutes ? ` (about ${msg.minutes} min)` : "";
  $("tour-phase").textContent = (PHASE_WORDS[msg.phase] || msg.phase) + where + (active ? "" : minutes);
  const reason = $("tour-reason");
  if (reason) reason.textContent = msg.phase === "paused" || msg.phase === "stopped" ? msg.reason || "" : "";
  $("tour-stops").replaceChildren(...(msg.stops || []).map(stopItem));
  const button = (id, on) => $(id) && ($(id).hidden = !on);
  button("tour-pause", msg.phase === "driving" || msg.phase === "at_stop");
  button("tour-resume", msg.phase === "paused");
  button("tour-skip", active);
  button("tour-stop", active);
}

async function command(name) {
  const { ok, data } = await api(`/api/tour/${name}`, {});
  const out = $("tour-msg");
  if (out) out.textContent = ok ? "" : data.error || `could not ${name}`;
  if (ok && data.tour) show(data.tour);
}

for (const name of ["pause", "resume", "skip", "stop"]) {
  const b = $(`tour-${name}`);
  if (b) b.addEventListener("click", () => command(name));
}

api("/api/tour").then(({ ok, data }) => ok && data.tour && show(data.tour));
new LiveSocket("/ws/status", { onMessage: (msg) => msg.type === "tour" && show(msg) });
