// bipedtele cockpit: a game controller (the Gamepad API, any OS) or the keyboard drives the
// leader (devices "gamepad" and "keyboard"), and the handle force comes back as rumble.
// Protocol: {"type": "pad", "src": "gamepad"|"keyboard", "x", "y", "held"} every 50 ms
// while a controller is in use (docs/cockpit.md). Page state for tests: window.cockpit.rumbles
// (the rumble effects issued, newest last) and window.cockpit.padSent.
"use strict";

(() => {
  const state = window.cockpit;
  state.forceMax = state.forceMax || 8.0;
  state.rumbles = [];
  state.padSent = 0;
  state.pad = null;
  const keys = { ArrowUp: false, ArrowDown: false, ArrowLeft: false, ArrowRight: false, " ": false };
  let keyboardUsed = false;
  let padStop = false;
  let keyStop = false;
  let lastRumble = 0;

  function gamepad() {
    const pads = (navigator.getGamepads ? Array.from(navigator.getGamepads()) : []).filter((g) => g && g.connected);
    return pads.find((g) => g.mapping === "standard") || pads[0] || null;
  }

  const pressed = (gp, i) => !!(gp.buttons[i] && gp.buttons[i].pressed);
  const clamp = (v) => Math.max(-1, Math.min(1, Number.isFinite(v) ? v : 0));
  const round = (v) => Math.round(v * 1e4) / 1e4;

  // The controller's state now: stick up/right, dead-man held (a stop latches until it is let go).
  function read() {
    const gp = gamepad();
    if (gp) {
      const dead = pressed(gp, 4) || pressed(gp, 5);  // LB, RB (standard mapping)
      if (pressed(gp, 1)) padStop = true;  // B
      if (!dead) padStop = false;
      return { src: "gamepad", x: clamp(gp.axes[0]), y: clamp(-gp.axes[1]), held: dead && !padStop, gp };
    }
    if (!keyboardUsed) return null;
    if (!keys[" "]) keyStop = false;
    const x = (keys.ArrowRight ? 1 : 0) - (keys.ArrowLeft ? 1 : 0);
    const y = (keys.ArrowUp ? 1 : 0) - (keys.ArrowDown ? 1 : 0);
    return { src: "keyboard", x, y, held: keys[" "] && !keyStop, gp: null };
  }

  function tick() {
    const p = read();
    state.pad = p;
    const label = document.getElementById("pad-src");
    if (!p) return;
    label.textContent = p.src === "gamepad"
      ? `controller: ${p.gp.id.slice(0, 40)}${p.held ? " (walking)" : " (hold LB/RB to walk)"}`
      : `controller: keyboard${p.held ? " (walking)" : " (hold space to walk)"}`;
    if (state.send({ type: "pad", src: p.src, x: round(p.x), y: round(p.y), held: p.held })) state.padSent += 1;
  }

  // The handle force the leader computes, as the gauge and the controller's dual rumble:
  // strong motor the forward axis, weak motor the turn axis, strength |f| / force_max_n.
  state.onForce = (s) => {
    const fv = typeof s.force_v === "number" ? Math.abs(s.force_v) : 0;
    const fw = typeof s.force_w === "number" ? Math.abs(s.force_w) : 0;
    const strong = Math.min(1, fv / state.forceMax);
    const weak = Math.min(1, fw / state.forceMax);
    document.getElementById("force-gauge").value = Math.max(strong, weak);
    document.getElementById("force-value").textContent = `${Math.hypot(fv, fw).toFixed(1)} N`;
    const p = state.pad;
    const gp = p && p.gp;
    const now = performance.now();
    if (!gp || now - lastRumble < 100) return;
    const effect = { startDelay: 0, duration: 150, strongMagnitude: round(strong), weakMagnitude: round(weak) };
    const act = gp.vibrationActuator;  // Chrome, Edge, Safari
    const haptic = gp.hapticActuators && gp.hapticActuators[0];  // Firefox: one motor
    try {
      if (act && typeof act.playEffect === "function") {
        Promise.resolve(act.playEffect("dual-rumble", effect)).catch(() => {});
      } else if (haptic && typeof haptic.pulse === "function") {
        Promise.resolve(haptic.pulse(Math.max(strong, weak), effect.duration)).catch(() => {});
      } else {
        return;
      }
    } catch (e) {
      return;  // a controller that refuses the effect: no rumble, the gauge still shows the force
    }
    lastRumble = now;
    state.rumbles.push({ t: Date.now() / 1000, force_v: fv, force_w: fw, ...effect });
    if (state.rumbles.length > 2000) state.rumbles.splice(0, 1000);
  };

  window.addEventListener("keydown", (ev) => {
    if (ev.key in keys) {
      keys[ev.key] = true;
      keyboardUsed = true;
      ev.preventDefault();
    } else if (ev.key === "Escape") {
      keyStop = true;
    }
  });
  window.addEventListener("keyup", (ev) => {
    if (ev.key in keys) {
      keys[ev.key] = false;
      ev.preventDefault();
    }
  });
  // A hidden page sends nothing: the leader reads a silent controller as let go.
  window.addEventListener("blur", () => { for (const k of Object.keys(keys)) keys[k] = false; });
  setInterval(tick, 50);
})();
