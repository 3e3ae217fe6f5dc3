// bipedtele cockpit: the predictive display, a top-down map on a <canvas> (no libraries).
// Draws the course's obstacles (from the server's hello), the robot's reported path and
// pose (as it was, h2 and more ago), and two ghosts from the leader's predictor: the
// predicted present pose (pred_*) and the pose h1 later (ahead_*), where the robot will be
// when a command sent now reaches it. World frame: x forward, y left, metres; yaw in rad.
"use strict";

const MAP_COLORS = { obstacle: "#8b949e", path: "#3fb950", robot: "#3fb950",
  ghost: "#f0b429", ahead: "#58a6ff", grid: "#21262d", text: "#9aa5b1" };

class MapView {
  constructor(canvas) {
    this.canvas = canvas;
    this.obstacles = [];   // [[x, y, r], ...]
    this.path = [];        // [[x, y], ...] reported positions
    this.pose = null;      // {x, y, yaw}
    this.ghost = null;     // predicted present
    this.ahead = null;     // predicted h1 later
    this.aheadDt = null;   // s
    this.view = null;      // {sx, ox, oy}: canvas = (ox + sx * x, oy - sx * y)
    this.draws = 0;
    this.ghostDrawn = false;
    this.dirty = true;
  }

  setCourse(obstacles) {
    this.obstacles = Array.isArray(obstacles) ? obstacles.filter(
      (o) => Array.isArray(o) && o.length === 3 && o.every((v) => typeof v === "number" && isFinite(v))) : [];
    this.dirty = true;
  }

  static _pose(s, p) {
    const x = s[p + "_x"], y = s[p + "_y"], yaw = s[p + "_yaw"];
    return (typeof x === "number" && typeof y === "number" && typeof yaw === "number") ? { x, y, yaw } : null;
  }

  push(s) {
    const pose = MapView._pose(s, "pose");
    if (pose) {
      const last = this.path[this.path.length - 1];
      if (!last || Math.hypot(pose.x - last[0], pose.y - last[1]) > 0.01) {
        this.path.push([pose.x, pose.y]);
        if (this.path.length > 5000) this.path.splice(0, this.path.length - 5000);
      }
      this.pose = pose;
    }
    this.ghost = MapView._pose(s, "pred");
    this.ahead = MapView._pose(s, "ahead");
    this.aheadDt = typeof s.ahead_dt === "number" ? s.ahead_dt : null;
    this.dirty = true;
  }

  // World -> canvas pixels (CSS pixels of the canvas' own resolution).
  toCanvas(x, y) {
    const v = this.view;
    return v ? [v.ox + v.sx * x, v.oy - v.sx * y] : null;
  }

  _fit(w, h) {
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    const add = (x, y, r) => { x0 = Math.min(x0, x - r); x1 = Math.max(x1, x + r);
      y0 = Math.min(y0, y - r); y1 = Math.max(y1, y + r); };
    for (const [x, y, r] of this.obstacles) add(x, y, r);
    for (const [x, y] of this.path) add(x, y, 0);
    for (const p of [this.pose, this.ghost, this.ahead]) if (p) add(p.x, p.y, 0);
    if (!isFinite(x0)) { x0 = -1; x1 = 1; y0 = -1; y1 = 1; }
    const m = 0.3; // m of margin
    x0 -= m; x1 += m; y0 -= m; y1 += m;
    const sx = Math.min(w / (x1 - x0), h / (y1 - y0));
    this.view = { sx, ox: (w - sx * (x1 + x0)) / 2, oy: (h + sx * (y1 + y0)) / 2 };
  }

  _robot(g, p, color, fill, dash) {
    const [cx, cy] = this.toCanvas(p.x, p.y);
    const L = Math.max(8, 0.2 * this.view.sx), W = 0.6 * L;
    const c = Math.cos(-p.yaw), s = Math.sin(-p.yaw);
    const pt = (a, b) => [cx + a * c - b * s, cy + a * s + b * c];
    g.beginPath();
    g.moveTo(...pt(L * 0.6, 0)); g.lineTo(...pt(-L * 0.4, W / 2)); g.lineTo(...pt(-L * 0.4, -W / 2));
    g.closePath();
    g.setLineDash(dash || []);
    if (fill) { g.fillStyle = color; g.fill(); }
    g.strokeStyle = color; g.lineWidth = 2; g.stroke();
    g.setLineDash([]);
  }

  draw() {
    const cv = this.canvas;
    const w = cv.clientWidth || cv.width, h = cv.clientHeight || cv.height;
    if (cv.width !== w || cv.height !== h) { cv.width = w; cv.height = h; }
    const g = cv.getContext("2d");
    g.clearRect(0, 0, w, h);
    this._fit(w, h);
    const sx = this.view.sx;
    // 0.5 m grid
    g.strokeStyle = MAP_COLORS.grid; g.lineWidth = 1;
    const [gx0, gy0] = [-this.view.ox / sx, (this.view.oy - h) / sx];
    g.beginPath();
    for (let x = Math.floor(gx0 / 0.5) * 0.5; x < gx0 + w / sx; x += 0.5) {
      const [px] = this.toCanvas(x, 0); g.moveTo(px, 0); g.lineTo(px, h);
    }
    for (let y = Math.floor(gy0 / 0.5) * 0.5; y < gy0 + h / sx; y += 0.5) {
      const [, py] = this.toCanvas(0, y); g.moveTo(0, py); g.lineTo(w, py);
    }
    g.stroke();
    g.fillStyle = MAP_COLORS.obstacle;
    for (const [x, y, r] of this.obstacles) {
      const [px, py] = this.toCanvas(x, y);
      g.beginPath(); g.arc(px, py, Math.max(2, r * sx), 0, 2 * Math.PI); g.fill();
    }
    if (this.path.length > 1) {
      g.strokeStyle = MAP_COLORS.path; g.globalAlpha = 0.6; g.lineWidth = 1.5;
      g.beginPath();
      this.path.forEach(([x, y], i) => { const [px, py] = this.toCanvas(x, y); if (i) g.lineTo(px, py); else g.moveTo(px, py); });
      g.stroke(); g.globalAlpha = 1;
    }
    if (this.ahead) this._robot(g, this.ahead, MAP_COLORS.ahead, false, [4, 3]);
    this.ghostDrawn = false;
    if (this.ghost) { this._robot(g, this.ghost, MAP_COLORS.ghost, true); this.ghostDrawn = true; }
    if (this.pose) this._robot(g, this.pose, MAP_COLORS.robot, false);
    g.fillStyle = MAP_COLORS.text; g.font = "11px sans-serif";
    const ahead = this.aheadDt === null ? "" : ` (+${(this.aheadDt * 1000).toFixed(0)} ms)`;
    g.fillText(`reported (green), predicted now (amber), in h1${ahead} (blue, dashed)`, 6, h - 6);
    this.draws += 1;
    this.dirty = false;
  }
}
