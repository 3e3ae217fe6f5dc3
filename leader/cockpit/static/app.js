// bipedtele cockpit page: websocket client, video, plots, status and the virtual joystick.
// Protocol: see bipedtele/leader/cockpit/protocol.py. Page state for tests: window.cockpit.
"use strict";

const KNOWN = new Set(["t", "ref_v", "ref_w", "z_e_v", "z_e_w", "eta_v", "eta_w", "force_v",
  "force_w", "h1_ms", "h2_ms", "alpha_m_v", "alpha_m_w", "s_r_v", "s_r_w", "T", "eps",
  "state", "link", "link_lost_s", "fb_age_ms", "loss_pct", "rx_kbps", "tx_kbps", "video_fps",
  "video_quality", "watchdog", "falls", "passes_done", "pose_x", "pose_y", "pose_yaw",
  "pred_x", "pred_y", "pred_yaw", "ahead_x", "ahead_y", "ahead_yaw", "ahead_dt",
  "held_by", "hand", "me"]);

const state = {
  wsOpen: false, connects: 0, framesReceived: 0, framesShown: 0, samplesReceived: 0, videoStale: 0,
  plotPoints: 0, joy: { x: 0, y: 0, active: false }, joySent: 0, lastSample: null,
};
window.cockpit = state;

// The predictive display (map.js): reported pose and path, ghosts of the predictions.
const map = new MapView(document.getElementById("map"));
state.map = map;

const C = { cmd: "#f0b429", robot: "#3fb950", eq: "#58a6ff", a: "#f778ba", b: "#a371f7",
  c: "#79c0ff", d: "#ffa657", tot: "#ff7b72" };

const plots = [
  new StripPlot(document.getElementById("plot-forward"), { title: "forward speed", unit: "cm/s",
    series: [{ key: "ref_v", label: "command", color: C.cmd },
             { key: "eta_v", label: "robot", color: C.robot },
             { key: "z_e_v", label: "z_e", color: C.eq, dash: [4, 3] }] }),
  new StripPlot(document.getElementById("plot-turn"), { title: "turn speed", unit: "deg/s",
    series: [{ key: "ref_w", label: "command", color: C.cmd },
             { key: "eta_w", label: "robot", color: C.robot },
             { key: "z_e_w", label: "z_e", color: C.eq, dash: [4, 3] }] }),
  new StripPlot(document.getElementById("plot-force"), { title: "force feedback", unit: "N",
    series: [{ key: "force_v", label: "forward axis", color: C.a },
             { key: "force_w", label: "turn axis", color: C.b }] }),
  new StripPlot(document.getElementById("plot-delay"), { title: "delay", unit: "ms",
    series: [{ key: "h1_ms", label: "h1", color: C.c },
             { key: "h2_ms", label: "h2", color: C.d },
             { label: "h1+h2", color: C.tot, fn: (s) =>
               (typeof s.h1_ms === "number" && typeof s.h2_ms === "number") ? s.h1_ms + s.h2_ms : null },
             { key: "fb_age_ms", label: "feedback age", color: C.robot, dash: [4, 3] }] }),
  new StripPlot(document.getElementById("plot-damping"), { title: "damping", unit: "",
    series: [{ key: "alpha_m_v", label: "alpha_m v", color: C.a },
             { key: "alpha_m_w", label: "alpha_m w", color: C.b },
             { key: "s_r_v", label: "s_r v", color: C.robot, dash: [4, 3] },
             { key: "s_r_w", label: "s_r w", color: C.eq, dash: [4, 3] }] }),
  new StripPlot(document.getElementById("plot-gait"), { title: "gait", unit: "s",
    series: [{ key: "T", label: "T", color: C.cmd },
             { key: "eps", label: "eps", color: C.c }] }),
];

// ------------------------------------------------------------------ status panel

const GOOD = new Set(["ok", "running", "walking", "standing", "up", "true"]);
const WARN = new Set(["stale", "waiting", "starting", "stopping", "feedback_stale", "unknown",
  "lossy", "capacity-limited"]);

// The link state in words (docs/cockpit.md): "link lost for 3.2 s", "no follower", ...
function linkWords(s) {
  const v = String(s.link);
  if (typeof s.blind === "string") return s.blind;  // the robot is stopped for old feedback (leader/blind.py)
  if (v === "lost") return typeof s.link_lost_s === "number" ? `link lost for ${s.link_lost_s.toFixed(1)} s` : "link lost";
  if (v === "no-follower" || v === "no follower") return "no follower";
  return v;
}
state.linkWords = linkWords;

function setPill(id, value, cls) {
  const el = document.getElementById(id);
  if (!el) return;
  el.querySelector("b").textContent = value;
  el.dataset.state = cls;
}

function classify(v) {
  const s = String(v).toLowerCase();
  if (GOOD.has(s)) return "ok";
  if (WARN.has(s)) return "warn";
  return "bad";
}

function showStatus(s) {
  if (s.link !== undefined) setPill("st-link", linkWords(s), classify(s.link));
  if (typeof s.fb_age_ms === "number") {
    setPill("st-age", `${s.fb_age_ms.toFixed(0)} ms`, s.fb_age_ms > 2000 ? "bad" : "unknown");
  }
  if (typeof s.loss_pct === "number") setPill("st-loss", `${s.loss_pct.toFixed(1)} %`, s.loss_pct > 2 ? "warn" : "ok");
  if (typeof s.rx_kbps === "number") {
    const of = typeof s.tx_kbps === "number" ? ` of ${s.tx_kbps.toFixed(0)}` : "";
    setPill("st-rx", `${s.rx_kbps.toFixed(0)}${of} kbit/s`, s.link === "capacity-limited" ? "warn" : "unknown");
  }
  if (typeof s.video_fps === "number") {
    const q = typeof s.video_quality === "number" ? `, q${s.video_quality}` : "";
    setPill("st-video", `${s.video_fps.toFixed(1)} fps${q}`, "unknown");
  }
  if (typeof s.watchdog === "number") setPill("st-watchdog", String(s.watchdog), s.watchdog > 0 ? "warn" : "ok");
  if (s.hand !== undefined) showHand(s);
  if (s.state !== undefined) setPill("st-state", String(s.state), classify(s.state));
  if (typeof s.falls === "number") setPill("st-falls", String(s.falls), s.falls > 0 ? "bad" : "ok");
  if (s.passes_done !== undefined) setPill("st-passes", String(s.passes_done), "unknown");
  if (typeof s.h1_ms === "number" && typeof s.h2_ms === "number") {
    setPill("st-delay", `${(s.h1_ms + s.h2_ms).toFixed(0)} ms`, "unknown");
  }
  const body = document.querySelector("#other tbody");
  const extra = Object.keys(s).filter((k) => !KNOWN.has(k)).sort();
  body.textContent = "";
  for (const k of extra) {
    const tr = document.createElement("tr");
    const a = document.createElement("td");
    const b = document.createElement("td");
    a.textContent = k;
    const v = s[k];
    b.textContent = typeof v === "number" ? (Number.isInteger(v) ? String(v) : v.toFixed(3))
      : JSON.stringify(v);
    tr.append(a, b);
    body.append(tr);
  }
}

function onSamples(samples) {
  for (const s of samples) {
    const t = typeof s.t === "number" ? s.t : performance.now() / 1000;
    for (const p of plots) p.push(t, s);
    map.push(s);
    state.samplesReceived += 1;
    state.lastSample = s;
  }
  if (state.lastSample && state.onForce) state.onForce(state.lastSample);
  state.plotPoints = plots.reduce((n, p) => n + p.points, 0);
  if (state.lastSample) showStatus(state.lastSample);
  document.getElementById("sample-count").textContent = String(state.samplesReceived);
}

// ------------------------------------------------------------------ video

const cams = new Map(); // camera -> {img, url, caption}
// A frame is shown as live only this long after it arrived [s] (the leader's video age bound):
// with no newer frame, the image is hidden and the caption says so.
const LIVE_VIDEO_S = 3.0;

function camera(name) {
  let cam = cams.get(name);
  if (cam) return cam;
  const ph = document.getElementById("no-video");
  if (ph) ph.remove();
  const fig = document.createElement("figure");
  const img = document.createElement("img");
  img.alt = `camera ${name}`;
  img.dataset.camera = name;
  const cap = document.createElement("figcaption");
  fig.append(img, cap);
  document.getElementById("video").append(fig);
  cam = { img, url: null, caption: cap, t: 0, n: 0, recv: 0 };
  img.addEventListener("load", () => {
    state.framesShown += 1;
    document.getElementById("frame-count").textContent = String(state.framesShown);
  });
  cams.set(name, cam);
  return cam;
}

function onFrame(buf) {
  const dv = new DataView(buf);
  if (buf.byteLength < 15 || dv.getUint8(0) !== 0x56 || dv.getUint8(1) !== 0x46) return;
  const len = dv.getUint8(2);
  const name = new TextDecoder().decode(new Uint8Array(buf, 3, len));
  const t = dv.getFloat64(3 + len, true);
  const n = dv.getUint32(11 + len, true);
  const jpeg = new Blob([new Uint8Array(buf, 15 + len)], { type: "image/jpeg" });
  const cam = camera(name);
  const old = cam.url;
  cam.url = URL.createObjectURL(jpeg);
  cam.img.src = cam.url;
  if (old) URL.revokeObjectURL(old);
  cam.t = t;
  cam.n = n;
  cam.recv = performance.now();
  cam.img.hidden = false;
  const age = Date.now() / 1000 - t;
  cam.caption.textContent = `${name} #${n}  age ${isFinite(age) ? (age * 1000).toFixed(0) : "?"} ms`;
  state.framesReceived += 1;
}

// No frame younger than the bound: never leave an old one up as if it were live.
setInterval(() => {
  const now = performance.now();
  for (const [name, cam] of cams) {
    const silent = (now - cam.recv) / 1000;
    if (silent > LIVE_VIDEO_S && !cam.img.hidden) {
      cam.img.hidden = true;
      state.videoStale += 1;
    }
    if (cam.img.hidden) cam.caption.textContent = `${name}: no live video for ${silent.toFixed(0)} s`;
  }
}, 250);

// ------------------------------------------------------------------ websocket

let ws = null;
// The access token: from the address the leader printed (?token=...); the server also set
// it as a cookie at the first page load, which the websocket carries as well.
const token = new URLSearchParams(location.search).get("token");
state.refused = null;

function connect() {
  const proto = location.protocol === "https:" ? "wss" : "ws";
  const query = token ? `?token=${encodeURIComponent(token)}` : "";
  ws = new WebSocket(`${proto}://${location.host}/ws${query}`);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => {
    state.wsOpen = true;
    state.connects += 1;
    setPill("st-ws", "connected", "ok");
  };
  ws.onclose = (ev) => {
    state.wsOpen = false;
    if (ev.code === 1013) {  // refused: too many clients; try again later
      setPill("st-ws", state.refused || "refused: too many clients", "bad");
      setTimeout(connect, 5000);
      return;
    }
    setPill("st-ws", "disconnected", "down");
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === "string") {
      let msg;
      try { msg = JSON.parse(ev.data); } catch (e) { return; }
      if (msg.type === "refused") state.refused = `refused: ${msg.reason}`;
      if (msg.type === "hello") {
        map.setCourse(msg.course);
        if (typeof msg.force_max_n === "number" && msg.force_max_n > 0) state.forceMax = msg.force_max_n;
      }
      if (msg.type === "samples" && Array.isArray(msg.samples)) onSamples(msg.samples);
    } else {
      onFrame(ev.data);
    }
  };
}

// Hand-over (docs/fleet.md): who holds the robot, and this operator's Release / Take.
function handWords(s) {
  const me = s.me || "";
  const held = typeof s.held_by === "string" ? s.held_by : null;
  if (s.hand === "released") return held && held !== me ? [`released; held by ${held}`, "unknown"] : ["released: free", "warn"];
  if (held === null) return ["taking", "unknown"];
  if (held === me) return [me ? `you (${me}) hold it` : "you hold it", "ok"];
  if (held === "") return ["free: taking it", "warn"];
  return [`held by ${held}: ask for release`, "bad"];
}
state.handWords = handWords;

function showHand(s) {
  const [words, cls] = handWords(s);
  setPill("st-hand", words, cls);
  const btn = document.getElementById("hand-btn");
  state.released = s.hand === "released";
  btn.textContent = state.released ? "Take" : "Release";
  btn.disabled = false;
}

document.getElementById("hand-btn").addEventListener("click", () => {
  if (!ws || ws.readyState !== WebSocket.OPEN) return;
  ws.send(JSON.stringify({ type: "hand", release: !state.released }));
});

// Send one JSON message to the server (false when the socket is not open); pad.js uses it.
state.send = (obj) => {
  if (!ws || ws.readyState !== WebSocket.OPEN) return false;
  ws.send(JSON.stringify(obj));
  return true;
};

function sendJoy() {
  if (!ws || ws.readyState !== WebSocket.OPEN) return;
  const r = (v) => Math.round(v * 1e4) / 1e4;
  ws.send(JSON.stringify({ type: "joy", x: r(state.joy.x), y: r(state.joy.y) }));
  state.joySent += 1;
}

// ------------------------------------------------------------------ joystick

const stick = document.getElementById("joystick");
let lastSend = 0;

function drawStick() {
  const g = stick.getContext("2d");
  const w = stick.width, h = stick.height, cx = w / 2, cy = h / 2, R = w * 0.4;
  g.clearRect(0, 0, w, h);
  g.strokeStyle = "#56606c"; g.lineWidth = 2;
  g.beginPath(); g.arc(cx, cy, R, 0, 2 * Math.PI); g.stroke();
  g.beginPath(); g.moveTo(cx - R, cy); g.lineTo(cx + R, cy); g.moveTo(cx, cy - R); g.lineTo(cx, cy + R); g.stroke();
  const kx = cx + state.joy.x * R, ky = cy - state.joy.y * R;
  g.fillStyle = state.joy.active ? "#f0b429" : "#8b949e";
  g.beginPath(); g.arc(kx, ky, w * 0.09, 0, 2 * Math.PI); g.fill();
  document.getElementById("joy-value").textContent =
    `x ${state.joy.x.toFixed(2)} y ${state.joy.y.toFixed(2)}`;
}

function stickPos(ev) {
  const r = stick.getBoundingClientRect();
  const R = r.width * 0.4;
  let x = (ev.clientX - (r.left + r.width / 2)) / R;
  let y = -(ev.clientY - (r.top + r.height / 2)) / R;
  const m = Math.hypot(x, y);
  if (m > 1) { x /= m; y /= m; }
  state.joy.x = Math.max(-1, Math.min(1, x));
  state.joy.y = Math.max(-1, Math.min(1, y));
}

stick.addEventListener("pointerdown", (ev) => {
  stick.setPointerCapture(ev.pointerId);
  state.joy.active = true;
  stickPos(ev);
  sendJoy(); lastSend = performance.now();
  drawStick();
});
stick.addEventListener("pointermove", (ev) => {
  if (!state.joy.active) return;
  stickPos(ev);
  const now = performance.now();
  if (now - lastSend > 30) { sendJoy(); lastSend = now; }
  drawStick();
});
function release() {
  if (!state.joy.active) return;
  state.joy.active = false;
  state.joy.x = 0; state.joy.y = 0;
  sendJoy(); lastSend = performance.now();
  drawStick();
}
stick.addEventListener("pointerup", release);
stick.addEventListener("pointercancel", release);
stick.addEventListener("lostpointercapture", release);
window.addEventListener("blur", release);
// While held, re-send the position every 100 ms: the leader treats silence as "centre".
setInterval(() => {
  if (state.joy.active && performance.now() - lastSend > 90) { sendJoy(); lastSend = performance.now(); }
}, 100);

// ------------------------------------------------------------------ render loop

function frame() {
  for (const p of plots) if (p.dirty) p.draw();
  if (map.dirty) map.draw();
  requestAnimationFrame(frame);
}

drawStick();
connect();
requestAnimationFrame(frame);
