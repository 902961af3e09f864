// Home page: what runs and how healthy it is.
import { $, api, healthRows } from "./common.js";

const REFRESH_MS = 2000;

async function refresh() {
  const { ok, data } = await api("/api/health");
  if (!ok) {
    $("summary").textContent = "the robot does not answer";
    return;
  }
  $("robot").textContent = data.robot;
  const nodes = Object.values(data.nodes);
  const running = nodes.filter((n) => n.state === "running").length;
  $("summary").textContent =
    `${data.simulated ? "Simulated robot" : "Real robot"} · ${running} of ${nodes.length} nodes running`;
  healthRows($("nodes"), data.nodes);
}

refresh();
setInterval(refresh, REFRESH_MS);
