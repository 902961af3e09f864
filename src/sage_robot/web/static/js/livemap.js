// The live map: map image, robot, lidar points, plan, goal, places, people, localization health.
// World frame: metres, x right, y up (map_server). The map image's top row is the highest y.
// Click (press and release without moving) -> onClick(x, y);
// drag -> onDrag(x, y, theta): a pose at the press point facing the release point.
// The goal marker shows every goal, whoever set it: a pose goal from /goal_pose, a place
// goal from /nav/state's place (drawn at that place, with its title).
// Optional layer: the navigator's costmap (/ws/live "costmap", a small RGBA PNG), setCostmap(on).
// Touch: two fingers pinch to zoom and pan (pinch.js).

import { Pinch } from "./pinch.js";

const DRAG_PX = 8; // a press that moves farther than this is a drag, not a click
const ROBOT_RADIUS_M = 0.25;
const ZOOM_MIN = 1;
const ZOOM_MAX = 16;
const ZOOM_STEP = 1.25; // one wheel notch or +/- press

export class LiveMap {
  constructor(canvas, { onClick = null, onDrag = null } = {}) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.onClick = onClick;
    this.onDrag = onDrag;
    this.meta = null; // {width, height, resolution, origin, version}
    this.image = null;
    this.layers = { pose: null, scan: [], plan: [], goal: null, people: [], loc: null, navPlace: "" };
    this.places = []; // [{name, title, x, y}] from setPlaces()
    this.pending = null; // a pose waiting for the operator's confirmation (drawn as a ghost robot)
    this.dragColor = "#3fb950";
    this.zoom = 1; // 1: the whole map fits the canvas
    this.center = null; // the world point at the canvas's centre (null: the map's centre)
    this.follow = false; // keep the robot at the centre
    this.panMode = false; // a drag moves the map instead of calling onDrag
    this.costmap = null; // {meta, image}: the navigator's latest costmap
    this.showCostmap = false;
    this.pinch = new Pinch(this);
    canvas.addEventListener("wheel", (e) => this.wheel(e), { passive: false });
    this.press = null;
    this.drawQueued = false;
    canvas.addEventListener("pointerdown", (e) => this.down(e));
    canvas.addEventListener("pointerup", (e) => this.up(e));
    canvas.addEventListener("pointermove", (e) => this.move(e));
    canvas.addEventListener("pointercancel", (e) => this.cancel(e));
    new ResizeObserver(() => this.redraw()).observe(canvas);
  }

  /** Feed a message from /ws/live. */
  update(msg) {
    switch (msg.type) {
      case "map":
        if (!this.meta || msg.version !== this.meta.version) this.loadMap(msg);
        return;
      case "costmap":
        this.loadCostmap(msg);
        return;
      case "pose":
        this.layers.pose = msg;
        break;
      case "scan":
        this.layers.scan = msg.points;
        break;
      case "plan":
        this.layers.plan = msg.points;
        break;
      case "goal":
        this.layers.goal = msg.x == null ? null : msg; // x null: no goal (navigation ended)
        break;
      case "people":
        this.layers.people = msg.points;
        break;
      case "loc":
        this.layers.loc = msg;
        break;
      case "nav":
        this.layers.navPlace = msg.done ? "" : msg.place || "";
        break;
      default:
        return;
    }
    this.redraw();
  }

  /** Places to draw (a dot and the title) and to mark when navigation goes to one. */
  setPlaces(places) {
    this.places = places || [];
    this.redraw();
  }

  /** A pose to draw as a ghost robot while it waits for a confirmation (null: none). */
  setPending(pose) {
    this.pending = pose;
    this.redraw();
  }

  loadMap(msg) {
    const img = new Image();
    img.onload = () => {
      this.meta = msg;
      this.image = img;
      this.canvas.dataset.mapVersion = String(msg.version);
      this.redraw();
    };
    img.src = msg.url;
  }

  loadCostmap(msg) {
    const img = new Image();
    img.onload = () => {
      this.costmap = { meta: msg, image: img };
      this.canvas.dataset.costmapStamp = String(msg.stamp);
      if (this.showCostmap) this.redraw();
    };
    img.src = `data:image/png;base64,${msg.png}`;
  }

  /** Show or hide the costmap layer. */
  setCostmap(on) {
    this.showCostmap = on;
    this.redraw();
  }

  /** Scale (pixels per metre) and offset: the map fitted into the canvas, times the zoom,
   * around the robot (following), the panned-to point or the map's centre. */
  view() {
    const w = this.canvas.clientWidth, h = this.canvas.clientHeight;
    if (!this.meta) return { scale: 20, ox: w / 2, oy: h / 2, w, h };
    const mw = this.meta.width * this.meta.resolution, mh = this.meta.height * this.meta.resolution;
    const scale = Math.min(w / mw, h / mh) * this.zoom;
    let [cx, cy] = this.center || [this.meta.origin.x + mw / 2, this.meta.origin.y + mh / 2];
    if (this.follow && this.layers.pose) [cx, cy] = [this.layers.pose.x, this.layers.pose.y];
    return { scale, ox: w / 2 - cx * scale, oy: h / 2 + cy * scale, w, h };
  }

  /** Zoom by ``factor`` keeping the world point under canvas pixel (px, py) in place. */
  zoomBy(factor, px = this.canvas.clientWidth / 2, py = this.canvas.clientHeight / 2) {
    const [wx, wy] = this.toWorld(px, py);
    this.zoomTo(this.zoom * factor, wx, wy, px, py);
  }

  /** Zoom to ``zoom`` with the world point (wx, wy) at canvas pixel (px, py) (when not following). */
  zoomTo(zoom, wx, wy, px, py) {
    const v = this.view();
    const old = this.zoom;
    this.zoom = Math.min(ZOOM_MAX, Math.max(ZOOM_MIN, zoom));
    const scale = v.scale * (this.zoom / old);
    if (!this.follow) this.center = [wx - (px - v.w / 2) / scale, wy + (py - v.h / 2) / scale];
    if (this.zoom === ZOOM_MIN && !this.pinch.active) this.center = null;
    this.redraw();
  }

  /** The whole map again. */
  fit() {
    this.zoom = 1;
    this.center = null;
    this.follow = false;
    this.redraw();
  }

  setFollow(on) {
    this.follow = on;
    if (!on && this.layers.pose) this.center = [this.layers.pose.x, this.layers.pose.y];
    this.redraw();
  }

  wheel(e) {
    e.preventDefault();
    const [px, py] = this.local(e);
    this.zoomBy(e.deltaY < 0 ? ZOOM_STEP : 1 / ZOOM_STEP, px, py);
  }

  toPx(x, y, v = this.view()) {
    return [v.ox + x * v.scale, v.oy - y * v.scale];
  }

  toWorld(px, py, v = this.view()) {
    return [(px - v.ox) / v.scale, (v.oy - py) / v.scale];
  }

  redraw() {
    if (this.drawQueued) return;
    this.drawQueued = true;
    requestAnimationFrame(() => {
      this.drawQueued = false;
      this.draw();
    });
  }

  draw() {
    const c = this.canvas, g = this.ctx;
    const dpr = window.devicePixelRatio || 1;
    if (c.width !== Math.round(c.clientWidth * dpr) || c.height !== Math.round(c.clientHeight * dpr)) {
      c.width = Math.round(c.clientWidth * dpr);
      c.height = Math.round(c.clientHeight * dpr);
    }
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    const v = this.view();
    g.fillStyle = "#222";
    g.fillRect(0, 0, v.w, v.h);
    if (this.image && this.meta) {
      const [x0, y0] = this.toPx(this.meta.origin.x, this.meta.origin.y + this.meta.height * this.meta.resolution, v);
      g.imageSmoothingEnabled = false;
      g.drawImage(this.image, x0, y0, this.meta.width * this.meta.resolution * v.scale,
        this.meta.height * this.meta.resolution * v.scale);
    }
    this.canvas.dataset.costmapShown = String(Boolean(this.showCostmap && this.costmap));
    if (this.showCostmap && this.costmap) this.drawGrid(this.costmap.meta, this.costmap.image, v);
    const L = this.layers;
    g.fillStyle = "#ff3b30";
    for (const [x, y] of L.scan) {
      const [px, py] = this.toPx(x, y, v);
      g.fillRect(px - 1.5, py - 1.5, 3, 3);
    }
    if (L.plan.length > 1) {
      g.strokeStyle = "#2f81f7";
      g.lineWidth = 3;
      g.beginPath();
      L.plan.forEach(([x, y], i) => {
        const [px, py] = this.toPx(x, y, v);
        if (i === 0) g.moveTo(px, py);
        else g.lineTo(px, py);
      });
      g.stroke();
    }
    g.font = "12px system-ui";
    const taken = []; // label boxes drawn: a label that would overlap one is left out
    for (const p of this.places) {
      const [px, py] = this.toPx(p.x, p.y, v);
      g.fillStyle = "#a371f7";
      g.beginPath();
      g.arc(px, py, 4, 0, 2 * Math.PI);
      g.fill();
      const text = p.title || p.name;
      const box = [px + 4, py - 17, px + 10 + g.measureText(text).width, py - 2];
      if (taken.some((b) => box[0] < b[2] && b[0] < box[2] && box[1] < b[3] && b[1] < box[3])) continue;
      taken.push(box);
      this.label(text, px + 6, py - 6);
    }
    const goal = L.goal || this.placeGoal();
    if (goal) {
      const [px, py] = this.toPx(goal.x, goal.y, v);
      g.strokeStyle = "#3fb950";
      g.lineWidth = 3;
      g.beginPath();
      g.arc(px, py, 9, 0, 2 * Math.PI);
      g.moveTo(px - 12, py);
      g.lineTo(px + 12, py);
      g.moveTo(px, py - 12);
      g.lineTo(px, py + 12);
      g.stroke();
      if (goal.theta != null) this.arrow(px, py, px + 22 * Math.cos(goal.theta), py - 22 * Math.sin(goal.theta), "#3fb950");
      if (goal.title) this.label(`goal: ${goal.title}`, px + 12, py + 18);
    }
    if (this.pending) this.drawRobot(this.pending, v, "rgba(242, 183, 5, 0.45)");
    g.fillStyle = "#ff9f0a";
    for (const [x, y] of L.people) {
      const [px, py] = this.toPx(x, y, v);
      g.beginPath();
      g.arc(px, py, Math.max(4, 0.25 * v.scale), 0, 2 * Math.PI);
      g.fill();
    }
    if (L.pose) this.drawRobot(L.pose, v);
    g.font = "13px system-ui";
    const notes = (L.loc ? 1 : 0) + (L.pose && L.pose.frame !== "map" ? 1 : 0);
    if (notes) {
      g.fillStyle = "rgba(16, 21, 28, 0.8)";
      g.fillRect(2, 4, 330, 18 * notes + 4);
    }
    if (L.loc) {
      g.fillStyle = L.loc.lost ? "#f85149" : "#e8eef5";
      g.fillText(`localization ${(L.loc.score * 100).toFixed(0)} %${L.loc.lost ? " · LOST" : ""}`, 8, 18);
    }
    if (L.pose && L.pose.frame !== "map") {
      g.fillStyle = "#d29922";
      g.fillText(`robot drawn from ${L.pose.frame} (not localized on the map)`, 8, 36);
    }
    if (this.press && this.press.dragging && !this.panMode) {
      this.arrow(this.press.px, this.press.py, this.press.qx, this.press.qy, this.dragColor);
    }
  }

  /** A grid image (top row = highest y) over its cells. */
  drawGrid(meta, image, v) {
    const g = this.ctx;
    const [x0, y0] = this.toPx(meta.origin.x, meta.origin.y + meta.height * meta.resolution, v);
    g.imageSmoothingEnabled = false;
    g.drawImage(image, x0, y0, meta.width * meta.resolution * v.scale, meta.height * meta.resolution * v.scale);
  }

  /** The place navigation is going to (from /nav/state), as a goal marker. */
  placeGoal() {
    const name = this.layers.navPlace;
    if (!name) return null;
    const p = this.places.find((q) => q.name === name);
    return p ? { x: p.x, y: p.y, theta: p.theta, title: p.title || p.name } : null;
  }

  label(text, x, y) {
    const g = this.ctx;
    const w = g.measureText(text).width;
    g.fillStyle = "rgba(16, 21, 28, 0.75)";
    g.fillRect(x - 2, y - 11, w + 4, 15);
    g.fillStyle = "#e8eef5";
    g.fillText(text, x, y);
  }

  arrow(x1, y1, x2, y2, color) {
    const g = this.ctx;
    const a = Math.atan2(y2 - y1, x2 - x1);
    g.strokeStyle = color;
    g.lineWidth = 2;
    g.beginPath();
    g.moveTo(x1, y1);
    g.lineTo(x2, y2);
    g.lineTo(x2 - 10 * Math.cos(a - 0.4), y2 - 10 * Math.sin(a - 0.4));
    g.moveTo(x2, y2);
    g.lineTo(x2 - 10 * Math.cos(a + 0.4), y2 - 10 * Math.sin(a + 0.4));
    g.stroke();
  }

  drawRobot(p, v, fill = "#f2b705") {
    const g = this.ctx;
    const [px, py] = this.toPx(p.x, p.y, v);
    const r = Math.max(7, ROBOT_RADIUS_M * v.scale);
    g.save();
    g.translate(px, py);
    g.rotate(-p.theta);
    g.fillStyle = fill;
    g.strokeStyle = "#000";
    g.beginPath();
    g.moveTo(r * 1.4, 0);
    g.lineTo(-r, r);
    g.lineTo(-r * 0.5, 0);
    g.lineTo(-r, -r);
    g.closePath();
    g.fill();
    g.stroke();
    g.restore();
  }

  local(e) {
    const rect = this.canvas.getBoundingClientRect();
    return [e.clientX - rect.left, e.clientY - rect.top];
  }

  down(e) {
    const [px, py] = this.local(e);
    this.canvas.setPointerCapture(e.pointerId);
    if (this.pinch.down(e.pointerId, px, py)) { // a second finger: a pinch, not a click or drag
      this.press = null;
      this.redraw();
      return;
    }
    if (this.pinch.spent) return;
    const v = this.view();
    const [cx, cy] = this.toWorld(v.w / 2, v.h / 2, v);
    this.press = { px, py, qx: px, qy: py, dragging: false, center: [cx, cy], scale: v.scale };
  }

  move(e) {
    const [qx, qy] = this.local(e);
    if (this.pinch.move(e.pointerId, qx, qy) || !this.press) return;
    Object.assign(this.press, { qx, qy });
    if (Math.hypot(qx - this.press.px, qy - this.press.py) > DRAG_PX) this.press.dragging = true;
    if (this.press.dragging && this.panMode) {
      const p = this.press;
      this.follow = false;
      this.center = [p.center[0] - (qx - p.px) / p.scale, p.center[1] + (qy - p.py) / p.scale];
    }
    if (this.press.dragging) this.redraw();
  }

  cancel(e) {
    this.pinch.up(e.pointerId);
    this.press = null;
    this.redraw();
  }

  up(e) {
    const p = this.press;
    this.press = null;
    if (this.pinch.up(e.pointerId)) {
      this.redraw();
      return;
    }
    if (!p) return;
    const [qx, qy] = this.local(e);
    const [x, y] = this.toWorld(p.px, p.py);
    if (this.panMode) {
      this.redraw(); // a pan ends where it is; a click in pan mode does nothing
      return;
    }
    if (Math.hypot(qx - p.px, qy - p.py) > DRAG_PX) {
      const [x2, y2] = this.toWorld(qx, qy);
      if (this.onDrag) this.onDrag(x, y, Math.atan2(y2 - y, x2 - x));
    } else if (this.onClick) {
      this.onClick(x, y);
    }
    this.redraw();
  }
}
