// Shared helpers of SAGE's pages: a WebSocket that reconnects by itself, JSON fetch, DOM.

const RECONNECT_MIN_MS = 500;
const RECONNECT_MAX_MS = 5000;

/** The ws:// or wss:// URL of a path on this server. */
export function wsUrl(path) {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  return `${proto}//${location.host}${path}`;
}

/**
 * A WebSocket that reconnects with a doubling delay.
 * onMessage(obj) gets each JSON message; onBinary(blob) each binary one;
 * onState(connected: bool) reports the link.
 */
export class LiveSocket {
  constructor(path, { onMessage = () => {}, onBinary = null, onState = () => {} } = {}) {
    this.path = path;
    this.onMessage = onMessage;
    this.onBinary = onBinary;
    this.onState = onState;
    this.delay = RECONNECT_MIN_MS;
    this.closed = false;
    this.ws = null;
    this.open();
  }

  open() {
    const ws = new WebSocket(wsUrl(this.path));
    if (this.onBinary) ws.binaryType = "blob";
    this.ws = ws;
    ws.onopen = () => {
      this.delay = RECONNECT_MIN_MS;
      this.onState(true);
    };
    ws.onmessage = (ev) => {
      if (typeof ev.data !== "string") {
        if (this.onBinary) this.onBinary(ev.data);
        return;
      }
      let msg;
      try {
        msg = JSON.parse(ev.data);
      } catch {
        return;
      }
      if (msg.type === "ping") this.send({ type: "pong", t: msg.t });
      this.onMessage(msg);
    };
    ws.onclose = () => {
      this.onState(false);
      if (this.closed) return;
      setTimeout(() => this.open(), this.delay);
      this.delay = Math.min(this.delay * 2, RECONNECT_MAX_MS);
    };
    ws.onerror = () => {}; // onclose follows and reconnects
  }

  get connected() {
    return this.ws !== null && this.ws.readyState === WebSocket.OPEN;
  }

  send(obj) {
    if (!this.connected) return false;
    this.ws.send(JSON.stringify(obj));
    return true;
  }

  close() {
    this.closed = true;
    if (this.ws) this.ws.close();
  }
}

/** POST (or GET without body) JSON; resolves to {ok, status, data}. Never throws on HTTP errors. */
export async function api(path, body = undefined, method = undefined) {
  const opts = { method: method || (body === undefined ? "GET" : "POST"), headers: {} };
  if (body !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  try {
    const resp = await fetch(path, opts);
    let data = {};
    try {
      data = await resp.json();
    } catch {
      data = {};
    }
    return { ok: resp.ok, status: resp.status, data };
  } catch (err) {
    return { ok: false, status: 0, data: { error: `network: ${err}` } };
  }
}

/** document.getElementById */
export const $ = (id) => document.getElementById(id);

/** Create an element: el("td", {class: "x"}, "text", child, ...) */
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k.startsWith("on") && typeof v === "function") node.addEventListener(k.slice(2), v);
    else if (v !== null && v !== undefined) node.setAttribute(k, v);
  }
  for (const c of children) node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return node;
}

/** Battery text: "15.2 V · 72 %" */
export function batteryText(msg) {
  if (!msg) return "—";
  if (msg.percentage === null || msg.percentage === undefined) {
    return msg.voltage === null || msg.voltage === undefined ? "battery unknown" : `${msg.voltage.toFixed(1)} V · ? %`;
  }
  const volts = msg.voltage === null || msg.voltage === undefined ? "" : `${msg.voltage.toFixed(1)} V · `;
  return `${volts}${Math.round(msg.percentage)} %`;
}

/** Fill a table body with node health rows. */
export function healthRows(tbody, nodes) {
  tbody.replaceChildren();
  for (const [name, h] of Object.entries(nodes)) {
    tbody.append(
      el(
        "tr",
        { class: `state-${h.state}` },
        el("td", {}, name + (h.critical ? " ★" : "")),
        el("td", {}, h.state),
        el("td", {}, h.restarts),
        el("td", {}, h.last_error || ""),
      ),
    );
  }
}

/** Operator pages: when a socket drops, check the session; if it expired, go to the login. */
export async function checkLogin() {
  const { ok, data } = await api("/api/whoami");
  if (ok && !data.operator) location.href = `/login?next=${encodeURIComponent(location.pathname)}`;
}
