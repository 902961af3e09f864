// Operator login: POST /api/login, then back to the page that asked.
import { $, api } from "./common.js";

function nextPage() {
  const next = new URLSearchParams(location.search).get("next") || "/teleop";
  // only a path on this server: "//host" and "/\\host" would leave it
  return /^\/(?![\/\\])/.test(next) && !next.includes("\\") ? next : "/teleop";
}

$("form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const { ok, data } = await api("/api/login", { password: $("password").value });
  if (ok) location.href = nextPage();
  else $("message").textContent = data.error || "login failed";
});
