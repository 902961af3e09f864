// Driving inputs -> {"type": "control", "x": m/s, "z": rad/s} on /ws/teleop.
// Sources, highest priority first: touch joystick, steering wheel + pedals, keyboard.
// A held command is re-sent every REPEAT_MS (the server's deadman stops the robot after
// 0.5 s of silence); a change is sent at once; releasing everything sends one zero.

const REPEAT_MS = 100;
const WHEEL_MAX_DEG = 135; // full lock of the on-screen wheel
const KEYS = {
  ArrowUp: "fwd", KeyW: "fwd", ArrowDown: "back", KeyS: "back",
  ArrowLeft: "left", KeyA: "left", ArrowRight: "right", KeyD: "right",
};

export class Drive {
  constructor(socket, { maxSpeed = 0.4, maxTurn = 1.0, onCommand = () => {} } = {}) {
    this.socket = socket;
    this.maxSpeed = maxSpeed;
    this.maxTurn = maxTurn;
    this.onCommand = onCommand;
    this.keys = new Set();
    this.wheelDeg = 0;
    this.throttle = false;
    this.brake = false;
    this.reverse = false;
    this.stick = null; // {x, y} in -1..1 while the joystick is held
    this.last = { x: 0, z: 0 };
    setInterval(() => this.tick(), REPEAT_MS);
  }

  command() {
    if (this.stick) {
      return { x: -this.stick.y * this.maxSpeed, z: -this.stick.x * this.maxTurn };
    }
    const steer = -this.wheelDeg / WHEEL_MAX_DEG;
    if (this.brake) return { x: 0, z: 0 };
    if (this.throttle || this.wheelDeg !== 0) {
      const x = this.throttle ? (this.reverse ? -1 : 1) * this.maxSpeed : 0;
      return { x, z: steer * this.maxTurn };
    }
    const k = this.keys;
    const has = (d) => [...k].some((code) => KEYS[code] === d);
    const x = (has("fwd") ? 1 : 0) - (has("back") ? 1 : 0);
    const z = (has("left") ? 1 : 0) - (has("right") ? 1 : 0);
    return { x: x * this.maxSpeed, z: z * this.maxTurn };
  }

  /** Send now when the command changed. */
  update() {
    const cmd = this.command();
    if (cmd.x !== this.last.x || cmd.z !== this.last.z) this.send(cmd);
  }

  tick() {
    const cmd = this.command();
    if (cmd.x !== 0 || cmd.z !== 0 || cmd.x !== this.last.x || cmd.z !== this.last.z) this.send(cmd);
  }

  send(cmd) {
    const round = (v) => Math.round(v * 1000) / 1000;
    const msg = { type: "control", x: round(cmd.x), z: round(cmd.z) };
    if (this.socket.send(msg)) this.last = { x: msg.x, z: msg.z };
    this.onCommand(msg);
  }

  releaseAll() {
    this.keys.clear();
    this.throttle = this.brake = false;
    this.stick = null;
    this.wheelDeg = 0;
    this.update();
  }

  // ------------------------------------------------------------ inputs
  bindKeys(target = window) {
    target.addEventListener("keydown", (e) => {
      if (e.target instanceof HTMLInputElement) return;
      if (!(e.code in KEYS)) return;
      e.preventDefault();
      if (e.repeat) return;
      this.keys.add(e.code);
      this.update();
    });
    target.addEventListener("keyup", (e) => {
      if (!(e.code in KEYS)) return;
      this.keys.delete(e.code);
      this.update();
    });
    window.addEventListener("blur", () => this.releaseAll());
  }

  bindWheel(wheel) {
    let start = null;
    const angleOf = (e) => {
      const r = wheel.getBoundingClientRect();
      return (Math.atan2(e.clientY - (r.top + r.height / 2), e.clientX - (r.left + r.width / 2)) * 180) / Math.PI;
    };
    const show = () => {
      wheel.style.transform = `rotate(${this.wheelDeg}deg)`;
      const deg = Math.round(this.wheelDeg);
      wheel.setAttribute("aria-valuenow", String(deg));
      wheel.setAttribute("aria-valuetext", deg === 0 ? "straight" : `${Math.abs(deg)}° ${deg > 0 ? "right" : "left"}`);
    };
    wheel.addEventListener("pointerdown", (e) => {
      wheel.setPointerCapture(e.pointerId);
      start = { a: angleOf(e), deg: this.wheelDeg };
    });
    wheel.addEventListener("pointermove", (e) => {
      if (!start) return;
      let d = angleOf(e) - start.a;
      if (d > 180) d -= 360;
      if (d < -180) d += 360;
      this.wheelDeg = Math.max(-WHEEL_MAX_DEG, Math.min(WHEEL_MAX_DEG, start.deg + d));
      show();
      this.update();
    });
    const end = () => {
      start = null;
      this.wheelDeg = 0; // the wheel springs back to centre
      show();
      this.update();
    };
    wheel.addEventListener("pointerup", end);
    wheel.addEventListener("pointercancel", end);
  }

  bindPedal(pedal, field) {
    const set = (on) => {
      this[field] = on;
      pedal.classList.toggle("pressed", on);
      pedal.setAttribute("aria-pressed", String(on));
      this.update();
    };
    pedal.addEventListener("pointerdown", (e) => {
      pedal.setPointerCapture(e.pointerId);
      set(true);
    });
    pedal.addEventListener("pointerup", () => set(false));
    pedal.addEventListener("pointercancel", () => set(false));
  }

  bindJoystick(pad, knob) {
    const place = (nx, ny) => {
      const r = pad.clientWidth / 2 - knob.clientWidth / 2;
      knob.style.transform = `translate(${nx * r}px, ${ny * r}px)`;
    };
    const at = (e) => {
      const b = pad.getBoundingClientRect();
      let nx = (e.clientX - (b.left + b.width / 2)) / (b.width / 2);
      let ny = (e.clientY - (b.top + b.height / 2)) / (b.height / 2);
      const n = Math.hypot(nx, ny);
      if (n > 1) [nx, ny] = [nx / n, ny / n];
      return { x: nx, y: ny };
    };
    pad.addEventListener("pointerdown", (e) => {
      pad.setPointerCapture(e.pointerId);
      this.stick = at(e);
      place(this.stick.x, this.stick.y);
      this.update();
    });
    pad.addEventListener("pointermove", (e) => {
      if (!this.stick) return;
      this.stick = at(e);
      place(this.stick.x, this.stick.y);
      this.update();
    });
    const end = () => {
      this.stick = null;
      place(0, 0);
      this.update();
    };
    pad.addEventListener("pointerup", end);
    pad.addEventListener("pointercancel", end);
  }
}
