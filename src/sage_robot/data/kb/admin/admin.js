// Admin page of the knowledge base: search, upload (with progress and cancel), list and delete documents.
const $ = (id) => document.getElementById(id);

function status(text, kind = "") {
  $("status").textContent = text;
  $("status").className = kind;
}

async function call(method, url, body) {
  const init = { method, credentials: "same-origin" };
  if (body instanceof FormData) init.body = body;
  else if (body !== undefined) {
    init.body = JSON.stringify(body);
    init.headers = { "Content-Type": "application/json" };
  }
  const response = await fetch(url, init);
  const data = response.status === 204 ? null : await response.json().catch(() => null);
  if (!response.ok) {
    const detail = data && data.detail;
    const message = typeof detail === "string" ? detail : JSON.stringify(detail || response.statusText);
    throw new Error(`${response.status}: ${message}`);
  }
  return data;
}

function cell(row, text) {
  const td = document.createElement("td");
  td.textContent = String(text);
  row.append(td);
  return td;
}

async function refresh() {
  const { documents } = await call("GET", "/api/kb/documents");
  const body = $("documents");
  body.replaceChildren();
  for (const doc of documents) {
    const row = document.createElement("tr");
    cell(row, doc.id); cell(row, doc.title); cell(row, doc.source); cell(row, doc.chunks); cell(row, doc.pages);
    const button = document.createElement("button");
    button.textContent = "Delete";
    button.addEventListener("click", async () => {
      if (!confirm(`Delete "${doc.title}"?`)) return;
      try { await call("DELETE", `/api/kb/documents/${doc.id}`); status(`Deleted ${doc.title}`, "ok"); }
      catch (err) { status(err.message, "error"); }
      await refresh();
    });
    cell(row, "").append(button);
    body.append(row);
  }
}

$("search-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const out = $("results");
  out.replaceChildren();
  try {
    const answer = await call("POST", "/api/kb/search", { query: $("query").value, top_k: Number($("top-k").value) });
    for (const r of answer.results) {
      const div = document.createElement("div");
      div.className = "result";
      const meta = document.createElement("div");
      meta.className = "meta";
      meta.textContent = `${r.title} — ${r.section} (score ${r.score.toFixed(4)}, similarity ${r.similarity.toFixed(2)})`;
      const text = document.createElement("div");
      text.textContent = r.content;
      div.append(meta, text);
      out.append(div);
    }
    status(`${answer.results.length} passages`, "ok");
  } catch (err) { status(err.message, "error"); }
});

function showProgress(p) {
  const bar = $("ingest-bar");
  bar.max = Math.max(p.documents_total, 1);
  bar.value = p.documents_done + (p.chunks_total ? p.chunks_done / p.chunks_total : 0);
  const chunks = p.chunks_total ? `, ${p.chunks_done} of ${p.chunks_total} passages` : "";
  const doing = p.current ? ` — ${p.current}${chunks}` : "";
  const what = p.state === "cancelling" ? "Cancelling" : "Ingesting";
  $("ingest-text").textContent = `${what}: ${p.documents_done} of ${p.documents_total} documents done${doing}`;
}

async function pollProgress() {
  try { showProgress(await call("GET", "/api/kb/ingest")); } catch (err) { /* the upload reports */ }
}

$("cancel").addEventListener("click", async () => {
  try { showProgress(await call("POST", "/api/kb/ingest/cancel")); }
  catch (err) { status(err.message, "error"); }
});

$("upload-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const files = $("files").files;
  if (!files.length) { status("Choose one or more files first", "error"); return; }
  const form = new FormData();
  for (const file of files) form.append("files", file);
  status("Uploading…");
  $("ingest").hidden = false;
  const timer = setInterval(pollProgress, 500);
  try {
    const { results } = await call("POST", "/api/kb/documents", form);
    const bad = results.some((r) => r.status === "failed" || r.status === "cancelled");
    status(results.map((r) => `${r.source}: ${r.status}${r.message ? " — " + r.message : ""}`).join("; "),
      bad ? "error" : "ok");
  } catch (err) { status(err.message, "error"); }
  clearInterval(timer);
  $("ingest").hidden = true;
  await refresh();
});

refresh().catch((err) => status(err.message, "error"));
