// The live map: map image, robot, lidar points, plan, goal, places, people, localization health.
// World frame: metres, x right, y up (map_server). The map image's top row is the highest y.
// Click (press and release without moving) -> onClick(x, y);
// drag -> onDrag(x, y, theta): a pose at the press point facing the release point.
// The goal marker shows every goal, whoever set it: a pose goal from /goal_pose, a place
// goal from /nav/state's place (drawn at that place, with its title).

const DRAG_PX = 8; // a press that moves farther than this is a drag, not a click
const ROBOT_RADIUS_M = 0.25;

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
    this.press = null;
    this.drawQueued = false;
    canvas.addEventListener("pointerdown", (e) => this.down(e));
    canvas.addEventListener("pointerup", (e) => this.up(e));
    canvas.addEventListener("pointermove", (e) => this.move(e));
    new ResizeObserver(() => this.redraw()).observe(canvas);
  }

  /** Feed a message from /ws/live. */
  update(msg) {
    switch (msg.type) {
      case "map":
        if (!this.meta || msg.version !== this.meta.version) this.loadMap(msg);
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

  /** Scale and offset that fit the map into the canvas (pixels per metre). */
  view() {
    const w = this.canvas.clientWidth, h = this.canvas.clientHeight;
    if (!this.meta) return { scale: 20, ox: w / 2, oy: h / 2, w, h };
    const mw = this.meta.width * this.meta.resolution, mh = this.meta.height * this.meta.resolution;
    const scale = Math.min(w / mw, h / mh);
    const ox = (w - mw * scale) / 2 - this.meta.origin.x * scale;
    const oy = (h + mh * scale) / 2 + this.meta.origin.y * scale;
    return { scale, ox, oy, w, h };
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
    for (const p of this.places) {
      const [px, py] = this.toPx(p.x, p.y, v);
      g.fillStyle = "#a371f7";
      g.beginPath();
      g.arc(px, py, 4, 0, 2 * Math.PI);
      g.fill();
      this.label(p.title || p.name, px + 6, py - 6);
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
    if (this.press && this.press.dragging) {
      this.arrow(this.press.px, this.press.py, this.press.qx, this.press.qy, this.dragColor);
    }
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
    this.press = { px, py, qx: px, qy: py, dragging: false };
    this.canvas.setPointerCapture(e.pointerId);
  }

  move(e) {
    if (!this.press) return;
    const [qx, qy] = this.local(e);
    Object.assign(this.press, { qx, qy });
    if (Math.hypot(qx - this.press.px, qy - this.press.py) > DRAG_PX) this.press.dragging = true;
    if (this.press.dragging) this.redraw();
  }

  up(e) {
    const p = this.press;
    this.press = null;
    if (!p) return;
    const [qx, qy] = this.local(e);
    const [x, y] = this.toWorld(p.px, p.py);
    if (Math.hypot(qx - p.px, qy - p.py) > DRAG_PX) {
      const [x2, y2] = this.toWorld(qx, qy);
      if (this.onDrag) this.onDrag(x, y, Math.atan2(y2 - y, x2 - x));
    } else if (this.onClick) {
      this.onClick(x, y);
    }
    this.redraw();
  }
}
