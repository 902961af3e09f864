// Two-finger pinch on the live map (phones, tablets): spreading the fingers zooms in, moving
// them together pans; the world point under the fingers' midpoint stays under it. Pointer
// events, so touch, pen and a test's synthetic pointers drive it alike. A press that becomes a
// pinch never clicks or drags (no goal, no pose) until every finger of it is lifted.

const MIN_SPREAD_PX = 1; // fingers closer than this count as this far apart

export class Pinch {
  constructor(map) {
    this.map = map;
    this.pointers = new Map(); // pointerId -> [x, y] on the canvas
    this.start = null; // {spread, zoom, wx, wy}: the pinch's start
    this.spent = false; // the fingers down have pinched: their releases do nothing else
  }

  get active() {
    return this.start !== null;
  }

  /** A finger down at canvas pixel (x, y); true when it starts a pinch (the press is dropped). */
  down(id, x, y) {
    this.pointers.set(id, [x, y]);
    if (this.pointers.size < 2) return false;
    this.begin();
    return true;
  }

  /** A finger moved; true when the pinch used it. */
  move(id, x, y) {
    if (!this.pointers.has(id)) return false;
    this.pointers.set(id, [x, y]);
    if (!this.start) return this.spent;
    const { spread, mx, my } = this.fingers();
    this.map.zoomTo(this.start.zoom * (spread / this.start.spread), this.start.wx, this.start.wy, mx, my);
    return true;
  }

  /** A finger lifted (or cancelled); true when it was part of a pinch. */
  up(id) {
    if (!this.pointers.delete(id)) return false;
    const spent = this.spent;
    if (this.pointers.size < 2) this.start = null;
    else this.begin(); // three fingers down, one lifted: go on from where the two are
    if (this.pointers.size === 0) this.spent = false;
    return spent;
  }

  begin() {
    const { spread, mx, my } = this.fingers();
    const [wx, wy] = this.map.toWorld(mx, my);
    this.start = { spread, zoom: this.map.zoom, wx, wy };
    this.spent = true;
  }

  fingers() {
    const [[ax, ay], [bx, by]] = [...this.pointers.values()];
    return { spread: Math.max(MIN_SPREAD_PX, Math.hypot(ax - bx, ay - by)), mx: (ax + bx) / 2, my: (ay + by) / 2 };
  }
}
