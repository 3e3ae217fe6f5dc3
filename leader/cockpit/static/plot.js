// bipedtele cockpit: a small strip-chart plotter on a <canvas> (no libraries).
// A StripPlot keeps the last `windowS` seconds of a few named series and redraws on demand.
"use strict";

const NICE_STEPS = [1, 2, 2.5, 5, 10];

function niceStep(span, count) {
  const raw = span / Math.max(1, count);
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const s of NICE_STEPS) {
    if (s * mag >= raw) return s * mag;
  }
  return 10 * mag;
}

function fmt(v, step) {
  const digits = Math.max(0, Math.min(4, -Math.floor(Math.log10(step) + 1e-9)));
  return v.toFixed(digits);
}

class StripPlot {
  // canvas: HTMLCanvasElement; opts: {title, unit, windowS, series: [{key, label, color, fn?}]}
  // A series takes sample[key], or fn(sample) when given; non-numbers leave a gap.
  constructor(canvas, opts) {
    this.canvas = canvas;
    this.title = opts.title;
    this.unit = opts.unit || "";
    this.windowS = opts.windowS || 30;
    this.series = opts.series;
    this.t = [];
    this.v = this.series.map(() => []);
    this.points = 0; // data points added since creation (all series)
    this.dirty = true;
  }

  push(t, sample) {
    if (typeof t !== "number" || !isFinite(t)) return;
    if (this.t.length && t < this.t[this.t.length - 1]) {
      // time went backwards (a new run): start over
      this.t = [];
      this.v = this.series.map(() => []);
    }
    this.t.push(t);
    this.series.forEach((s, i) => {
      const raw = s.fn ? s.fn(sample) : sample[s.key];
      const ok = typeof raw === "number" && isFinite(raw);
      this.v[i].push(ok ? raw : null);
      if (ok) this.points += 1;
    });
    const tmin = t - this.windowS;
    let cut = 0;
    while (cut < this.t.length && this.t[cut] < tmin) cut++;
    if (cut > 0) {
      this.t.splice(0, cut);
      this.v.forEach((arr) => arr.splice(0, cut));
    }
    this.dirty = true;
  }

  draw() {
    const c = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(50, c.clientWidth), h = Math.max(40, c.clientHeight);
    if (c.width !== Math.round(w * dpr) || c.height !== Math.round(h * dpr)) {
      c.width = Math.round(w * dpr);
      c.height = Math.round(h * dpr);
    }
    const g = c.getContext("2d");
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, h);
    g.font = "11px sans-serif";
    const L = 46, R = 14, T = 20, B = 18;
    const pw = w - L - R, ph = h - T - B;

    // ranges
    const tmax = this.t.length ? this.t[this.t.length - 1] : 0;
    const tmin = tmax - this.windowS;
    let ymin = Infinity, ymax = -Infinity;
    for (const arr of this.v) {
      for (const y of arr) {
        if (y === null) continue;
        if (y < ymin) ymin = y;
        if (y > ymax) ymax = y;
      }
    }
    if (!isFinite(ymin)) { ymin = -1; ymax = 1; }
    if (ymax - ymin < 1e-6) { ymin -= 0.5; ymax += 0.5; }
    const pad = 0.08 * (ymax - ymin);
    ymin -= pad; ymax += pad;
    const X = (t) => L + ((t - tmin) / this.windowS) * pw;
    const Y = (y) => T + (1 - (y - ymin) / (ymax - ymin)) * ph;

    // grid and ticks
    g.strokeStyle = "#2c3440";
    g.fillStyle = "#9aa5b1";
    g.lineWidth = 1;
    const ys = niceStep(ymax - ymin, 4);
    g.textAlign = "right";
    g.textBaseline = "middle";
    for (let y = Math.ceil(ymin / ys) * ys; y <= ymax; y += ys) {
      const py = Math.round(Y(y)) + 0.5;
      g.beginPath(); g.moveTo(L, py); g.lineTo(L + pw, py); g.stroke();
      g.fillText(fmt(y, ys), L - 4, py);
    }
    const ts = niceStep(this.windowS, 6);
    g.textAlign = "center";
    g.textBaseline = "top";
    for (let r = 0; r <= this.windowS + 1e-9; r += ts) {
      const px = Math.round(X(tmax - r)) + 0.5;
      g.beginPath(); g.moveTo(px, T); g.lineTo(px, T + ph); g.stroke();
      g.fillText(r === 0 ? "now" : "-" + fmt(r, ts) + " s", px, T + ph + 3);
    }
    g.strokeStyle = "#56606c";
    g.strokeRect(L + 0.5, T + 0.5, pw, ph);

    // series
    g.save();
    g.beginPath(); g.rect(L, T, pw, ph); g.clip();
    this.series.forEach((s, i) => {
      const arr = this.v[i];
      g.strokeStyle = s.color;
      g.lineWidth = s.width || 1.5;
      g.setLineDash(s.dash || []);
      g.beginPath();
      let pen = false;
      for (let k = 0; k < arr.length; k++) {
        if (arr[k] === null) { pen = false; continue; }
        const px = X(this.t[k]), py = Y(arr[k]);
        if (pen) g.lineTo(px, py); else g.moveTo(px, py);
        pen = true;
      }
      g.stroke();
    });
    g.restore();
    g.setLineDash([]);

    // title and legend
    g.textAlign = "left";
    g.textBaseline = "top";
    g.fillStyle = "#e6edf3";
    g.font = "bold 12px sans-serif";
    const title = this.unit ? `${this.title} [${this.unit}]` : this.title;
    g.fillText(title, 4, 3);
    let lx = 8 + g.measureText(title).width + 12;
    g.font = "11px sans-serif";
    this.series.forEach((s, i) => {
      const arr = this.v[i];
      const last = arr.length ? arr[arr.length - 1] : null;
      const label = last === null ? s.label : `${s.label} ${last.toFixed(2)}`;
      g.fillStyle = s.color;
      g.fillRect(lx, 8, 10, 3);
      g.fillStyle = "#c9d1d9";
      g.fillText(label, lx + 13, 4);
      lx += 13 + g.measureText(label).width + 12;
    });
    this.dirty = false;
  }
}

window.StripPlot = StripPlot;
