// Admin: knowledge base, places (list, add at the robot or a clicked point), node health, logs.
import { $, api, checkLogin, el, healthRows, LiveSocket } from "./common.js";
import { LiveMap } from "./livemap.js";
import { loadPlaces as fetchPlaces } from "./places.js";

const REFRESH_MS = 3000;

async function loadPlaces() {
  const places = await fetchPlaces("/api/admin/places");
  if (!places) return;
  const body = $("places");
  body.replaceChildren();
  for (const p of places) { // the human title; the code name in its tooltip
    body.append(el("tr", { "data-place": p.name }, el("td", { title: p.name }, p.title),
      el("td", { class: "nowrap" }, `${p.x.toFixed(2)}, ${p.y.toFixed(2)}`), el("td", {}, p.description)));
  }
  map.setPlaces(places);
}

async function addPlace(extra) {
  const body = {
    name: $("p-name").value.trim(),
    description: $("p-desc").value,
    aliases: $("p-aliases").value,
    ...extra,
  };
  const { ok, data } = await api("/api/admin/places", body);
  $("place-msg").className = ok ? "ok" : "error";
  $("place-msg").textContent = ok
    ? `added ${body.name} to ${data.file} (navigation re-reads it now)`
    : data.error;
  if (ok) loadPlaces();
}

$("add-place").addEventListener("submit", (ev) => {
  ev.preventDefault();
  addPlace({ x: Number($("p-x").value), y: Number($("p-y").value), theta: Number($("p-theta").value || 0) });
});
$("add-at-robot").addEventListener("click", () => addPlace({ at_robot: true }));

const map = new LiveMap($("map"), {
  onClick: (x, y) => {
    $("p-x").value = x.toFixed(2);
    $("p-y").value = y.toFixed(2);
  },
});
new LiveSocket("/ws/live", { onMessage: (msg) => map.update(msg), onState: (up) => up || checkLogin() });
window.sageMap = map; // for debugging from the console (and the browser tests)

async function loadInfo() {
  const { ok, data } = await api("/api/admin/info");
  if (!ok) return;
  const wp = data.waypoints;
  $("waypoints-file").textContent = `— ${wp.name}${wp.shipped ? " (shipped with SAGE, read-only)" : ""}`;
  $("waypoints-file").title = wp.path;
  if (!wp.writable) {
    for (const id of ["add-at-point", "add-at-robot"]) $(id).disabled = true;
    $("place-msg").className = "error";
    $("place-msg").textContent = `Places cannot be added: ${wp.name} is ${wp.note}.`;
  }
  const kb = $("kb");
  if (data.kb) {
    kb.replaceChildren(el("p", { class: "muted" }, data.kb));
    return;
  }
  const docs = await api("/api/kb/documents");
  kb.replaceChildren();
  if (!docs.ok) {
    kb.append(el("p", { class: "error" }, docs.data.error || "the knowledge base does not answer"));
    return;
  }
  const list = Array.isArray(docs.data) ? docs.data : docs.data.documents || [];
  kb.append(el("p", {}, `${list.length} documents · `, el("a", { href: "/kb/admin" }, "manage documents")));
  const ul = el("ul");
  for (const d of list.slice(0, 50)) ul.append(el("li", {}, d.source || d.title || d.name || JSON.stringify(d)));
  kb.append(ul);
}

async function refresh() {
  const health = await api("/api/health");
  if (health.ok) healthRows($("nodes"), health.data.nodes);
  const logs = await api("/api/admin/logs?limit=200");
  if (logs.ok) {
    const box = $("logs");
    box.replaceChildren(
      ...logs.data.records.reverse().map((r) => {
        const fields = Object.entries(r.fields).map(([k, v]) => `${k}=${v}`).join(" ");
        const t = new Date(r.t * 1000).toLocaleTimeString();
        return el("div", { class: r.level === "error" ? "error" : "" }, `${t} ${r.level} ${r.node} ${r.msg} ${fields}`);
      }),
    );
  }
}

$("logout").addEventListener("click", async (ev) => {
  ev.preventDefault();
  await api("/api/logout", {});
  location.href = "/";
});

loadInfo();
loadPlaces();
refresh();
setInterval(refresh, REFRESH_MS);
