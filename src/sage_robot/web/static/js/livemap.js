// The live map: map image, robot, lidar points, plan, goal, people, localization health.
// World frame: metres, x right, y up (map_server). The map image's top row is the highest y.
// Click (press and release without moving) -> onClick(x, y);
// drag -> onDrag(x, y, theta): a pose at the press point facing the release point.

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
    this.layers = { pose: null, scan: [], plan: [], goal: null, people: [], loc: null };
    this.press = null;
    this.pending = false;
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
      default:
        return;
    }
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
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
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
    if (L.goal) {
      const [px, py] = this.toPx(L.goal.x, L.goal.y, v);
      g.strokeStyle = "#3fb950";
      g.lineWidth = 3;
      g.beginPath();
      g.arc(px, py, 9, 0, 2 * Math.PI);
      g.moveTo(px - 12, py);
      g.lineTo(px + 12, py);
      g.moveTo(px, py - 12);
      g.lineTo(px, py + 12);
      g.stroke();
    }
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
      const [x1, y1] = [this.press.px, this.press.py], [x2, y2] = [this.press.qx, this.press.qy];
      g.strokeStyle = "#f2b705";
      g.lineWidth = 2;
      g.beginPath();
      g.moveTo(x1, y1);
      g.lineTo(x2, y2);
      g.stroke();
    }
  }

  drawRobot(p, v) {
    const g = this.ctx;
    const [px, py] = this.toPx(p.x, p.y, v);
    const r = Math.max(7, ROBOT_RADIUS_M * v.scale);
    g.save();
    g.translate(px, py);
    g.rotate(-p.theta);
    g.fillStyle = "#f2b705";
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
