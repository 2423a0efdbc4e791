// The trainer in a headset (WebXR): "Enter headset" buttons where the browser offers immersive-ar
// (passthrough) or immersive-vr, the scene at true scale (metres), its panels as in-scene text
// readable at arm's length, and a controller (or a hand) as the probe (navigation: its tip, 8 cm
// along its ray, takes landmarks while the trigger is held) or the reamer (reaming: its ray is the
// shaft; the trigger's pressure × the trainer's largest push is the push, and pressing it runs the
// reamer) whenever no tracker streams that tool and no force sensor the push. B or Y (a hand: a
// long pinch) calibrates the headset against the tracker: held in the calibration target's cradle,
// the controller's pose is sampled for a second and the server places the scene where the tracker
// sees the phantom (the residual is shown). Pages call attachHeadset once; nothing here runs until
// a session starts.
import * as THREE from "three";

const PROBE_TIP_M = 0.08; // the virtual probe's needle along the controller's ray
const SEND_EVERY_MS = 33; // poses sent at most ~30 times a second
const AIM_STEP_RAD = THREE.MathUtils.degToRad(0.5); // a reamer aim is sent when it turned this much
const PUSH_STEP_N = 5; // a push is sent when it changed this much
const PRESSED = 0.05; // a trigger beyond this is pressed
const PANEL_PX_PER_M = 2800; // a panel's canvas resolution: 40 px letters are 14 mm tall, ~1.2° at 0.7 m
// Before calibration the operated hip sits here (local-floor: metres above the floor, ahead of the user).
const HIP_AT = new THREE.Vector3(0, 1.0, -0.55);

const ROW = new THREE.Matrix4();
const INVERSE = new THREE.Matrix4();
const POINT = new THREE.Vector3();
const AXIS = new THREE.Vector3();

// Row-major 16 numbers of a matrix (the server's convention).
const rowMajor = (matrix) => ROW.copy(matrix).transpose().toArray();

// A panel: text drawn on a canvas, shown on a plane (its texture redrawn only when its lines change).
class Panel {
  constructor(widthM, heightM) {
    this.canvas = document.createElement("canvas");
    this.canvas.width = Math.round(widthM * PANEL_PX_PER_M);
    this.canvas.height = Math.round(heightM * PANEL_PX_PER_M);
    this.texture = new THREE.CanvasTexture(this.canvas);
    this.texture.colorSpace = THREE.SRGBColorSpace;
    this.mesh = new THREE.Mesh(new THREE.PlaneGeometry(widthM, heightM), new THREE.MeshBasicMaterial({ map: this.texture, transparent: true }));
    this.shown = "";
  }

  // lines: [text, colour] pairs; the first is the title.
  show(lines) {
    const look = JSON.stringify(lines);
    if (look === this.shown) return;
    this.shown = look;
    const g = this.canvas.getContext("2d");
    g.clearRect(0, 0, this.canvas.width, this.canvas.height);
    g.fillStyle = "rgba(20, 24, 30, 0.88)";
    g.beginPath();
    g.roundRect(0, 0, this.canvas.width, this.canvas.height, 28);
    g.fill();
    lines.forEach(([text, colour], i) => {
      g.fillStyle = colour ?? "#e8edf2";
      g.font = i === 0 ? "bold 48px sans-serif" : "40px sans-serif";
      g.fillText(text, 32, 70 + i * 58, this.canvas.width - 64);
    });
    this.texture.needsUpdate = true;
  }
}

const ZONE_CSS = { green: "#00c850", amber: "#ffb000", red: "#ff5050" };
const fixed = (x, digits = 1) => (x === null || x === undefined ? "—" : x.toFixed(digits));

// What the panels say: the score (angles, registration or reaming figures) and the status
// (headset calibration, tracking, what the controller does).
function scoreLines(s, tool) {
  const angles = s.angles ? s.angles[s.definition] : null;
  const zone = s.zone ? (s.zone.inside ? "inside the safe zone" : `${s.zone.distance_deg.toFixed(1)}° outside the safe zone`) : s.note;
  const lines = [
    [tool === "probe" ? "Navigation" : "Reaming"],
    [`Inclination ${angles ? fixed(angles[0]) : "—"}° · anteversion ${angles ? fixed(angles[1]) : "—"}°`, s.zone ? ZONE_CSS[s.zone.colour] : null],
    [zone || ""],
  ];
  if (tool === "probe") {
    const reg = s.registration;
    lines.push([`Landmarks ${reg.acquired.length} / ${reg.total}`]);
    lines.push([reg.done ? `registered · fit error ${reg.rms_mm.toFixed(2)} mm` : `next: ${(reg.current ?? "—").replaceAll("_", " ")}`]);
  } else {
    const r = s.reaming;
    lines.push([`Removed ${r.removed_volume_mm3.toFixed(0)} mm³ · depth ${r.depth_mm.toFixed(2)} mm`]);
    lines.push([`Push ${r.force_n.toFixed(0)} N (${r.force_source}) · ${r.running ? "reaming" : "paused"}`]);
    if (r.note) lines.push([r.note, "#ffb000"]);
  }
  return lines;
}

function statusLines(s, tool) {
  const h = s.headset;
  const calibration =
    h.state === "sampling" ? `calibrating ${h.samples} / ${h.needed}: hold still` :
    h.state === "done" ? `calibrated · residual ${h.result.rotation_residual_rms_deg.toFixed(2)}° / ${h.result.translation_residual_rms_mm.toFixed(1)} mm` :
    h.state === "refused" ? `calibration refused: ${h.message}` : "not calibrated: controller in the target's cradle, press B";
  const tracked = Object.entries(s.tools).map(([name, t]) => `${name} ${t.tracked ? "✓" : "✗"}`).join(" · ");
  return [
    ["Headset"],
    [calibration, h.state === "refused" ? "#ff5050" : h.state === "done" ? "#00c850" : null],
    [`Tracking: ${tracked}`],
    [tool === "probe" ? "Trigger: probe the glowing landmark" : "Trigger: push and ream (harder: more force)"],
  ];
}

// Hooks the headset into a page: `view` its NavigationScene, `stats` its figures (the last state,
// the hello), `send` its control sender, `tool` "probe" or "reamer". Shows the buttons the browser
// supports; returns the headset's handle (also window.trainer.xr, for tests and the benchmark).
export function attachHeadset(view, stats, send, tool) {
  const renderer = view.renderer;
  const headset = {
    session: null, mode: null, frames: 0, sent: { probe: 0, aim: 0, push: 0, targets: 0 },
    timing: { measure: false, drawMs: [], calls: 0, triangles: 0 },
    controllers: [], panels: null,
  };
  window.trainer.xr = headset;
  if (!navigator.xr) return headset;

  const bar = document.getElementById("topbar");
  for (const [mode, label, title] of [
    ["immersive-ar", "Enter headset (passthrough)", "The trainer in a headset over the room (Meta Quest: passthrough)"],
    ["immersive-vr", "Enter headset (VR)", "The trainer in a headset, fully virtual"],
  ]) {
    navigator.xr.isSessionSupported(mode).then((supported) => {
      if (!supported) return;
      const button = document.createElement("button");
      button.id = mode === "immersive-ar" ? "enter-ar" : "enter-vr";
      button.className = "headset";
      button.textContent = label;
      button.title = title;
      button.addEventListener("click", () => start(mode).catch((error) => stats.errors.push(`headset: ${error.message}`)));
      bar.append(button);
    }).catch(() => {});
  }

  async function start(mode) {
    const session = await navigator.xr.requestSession(mode, { optionalFeatures: ["local-floor", "hand-tracking"] });
    renderer.xr.enabled = true;
    renderer.xr.setReferenceSpaceType("local-floor");
    await renderer.xr.setSession(session);
    headset.session = session;
    headset.mode = mode;
    enter(mode);
    session.addEventListener("end", leave);
    renderer.setAnimationLoop(frame);
  }

  const flat = {};
  function enter(mode) {
    flat.background = view.scene.background;
    if (mode === "immersive-ar") {
      view.scene.background = null; // the room shows through
      renderer.setClearColor(0x000000, 0);
    }
    view.scene.traverse((object) => { if (object.type === "GridHelper") { object.visible = false; } });
    view.root.matrixAutoUpdate = false;
    if (!headset.panels) buildPanels();
    for (const panel of Object.values(headset.panels)) view.scene.add(panel.mesh);
    if (!headset.controllers.length) for (const index of [0, 1]) addController(index);
    for (const c of headset.controllers) view.scene.add(c.ray, c.grip);
  }

  function leave() {
    renderer.setAnimationLoop(null);
    headset.session = null;
    view.scene.background = flat.background;
    renderer.setClearColor(0x000000, 1);
    view.scene.traverse((object) => { if (object.type === "GridHelper") object.visible = true; });
    view.root.matrix.identity();
    view.root.matrixAutoUpdate = true;
    for (const panel of Object.values(headset.panels)) view.scene.remove(panel.mesh);
    for (const c of headset.controllers) view.scene.remove(c.ray, c.grip);
    renderer.xr.enabled = false;
    renderer.setSize(...view.size, false);
  }

  // The panels stand side by side beyond the hip, facing the user, at arm's length (0.8 m).
  function buildPanels() {
    const score = new Panel(0.42, 0.24), status = new Panel(0.42, 0.22);
    score.mesh.position.set(-0.22, 1.3, -0.78);
    status.mesh.position.set(0.22, 1.3, -0.78);
    for (const p of [score, status]) p.mesh.lookAt(0, 1.55, 0);
    headset.panels = { score, status };
  }

  function addController(index) {
    const ray = renderer.xr.getController(index), grip = renderer.xr.getControllerGrip(index);
    const c = { ray, grip, source: null, pressed: false, calibrate: false };
    // The tool in the hand: a probe's needle, or the reamer's shaft along the ray (toward the hand).
    const needle = tool === "probe"
      ? new THREE.CylinderGeometry(0.0015, 0.0015, PROBE_TIP_M, 8).rotateX(Math.PI / 2).translate(0, 0, -PROBE_TIP_M / 2)
      : new THREE.CylinderGeometry(0.005, 0.005, 0.2, 10).rotateX(Math.PI / 2).translate(0, 0, 0.1);
    ray.add(new THREE.Mesh(needle, new THREE.MeshLambertMaterial({ color: 0xb0b8c0 })));
    grip.add(new THREE.Mesh(new THREE.BoxGeometry(0.03, 0.03, 0.1), new THREE.MeshLambertMaterial({ color: 0x30363d })));
    ray.addEventListener("connected", (event) => { c.source = event.data; });
    ray.addEventListener("disconnected", () => { c.source = null; });
    ray.addEventListener("selectstart", () => { c.selecting = true; c.selectStarted = performance.now(); });
    ray.addEventListener("selectend", () => { c.selecting = false; });
    headset.controllers.push(c);
  }

  // The hand holding the tool: the right one, else any.
  const toolHand = () => headset.controllers.find((c) => c.source?.handedness === "right") ?? headset.controllers.find((c) => c.source);

  function place(s) {
    if (s?.headset?.placement) {
      view.root.matrix.set(...s.headset.placement);
    } else if (view.focus) {
      view.root.matrix.makeTranslation(HIP_AT.x - view.focus.x, HIP_AT.y - view.focus.y, HIP_AT.z - view.focus.z);
    }
    view.root.matrixWorldNeedsUpdate = true;
  }

  // World (the headset's space) to the scene's frame (the server's model frame).
  function toScene(point) {
    view.root.updateMatrixWorld();
    return point.applyMatrix4(INVERSE.copy(view.root.matrixWorld).invert());
  }

  function useControllers(now, s) {
    const hand = toolHand();
    for (const c of headset.controllers) {
      const pad = c.source?.gamepad;
      const calibrate = pad ? Boolean(pad.buttons[5]?.pressed) : c.selecting && now - c.selectStarted > 2000;
      if (calibrate && !c.calibrate) {
        send({ type: "headset", action: "start" });
        headset.sent.targets = 0;
        headset.calibrating = s.headset.needed;
        headset.calibrator = c; // the controller in the cradle: the one whose button was pressed
      }
      c.calibrate = calibrate;
    }
    if (headset.calibrating > 0) {
      send({ type: "headset", action: "target", pose: rowMajor(headset.calibrator.grip.matrixWorld) });
      headset.sent.targets += 1;
      headset.calibrating -= 1;
      return; // still on the target: it probes or reams nothing
    }
    if (!hand?.source) return;
    const pad = hand.source.gamepad;
    const value = pad ? pad.buttons[0]?.value ?? 0 : hand.selecting ? 1 : 0;
    if (tool === "probe") probe(now, s, hand, value);
    else ream(now, s, hand, value, Boolean(pad));
  }

  function probe(now, s, hand, value) {
    if (s.registration.done || s.tools.Probe?.source === "tracker") return;
    const pressed = value > PRESSED;
    if (pressed && now - headset.lastProbe > SEND_EVERY_MS) {
      const tip = toScene(POINT.set(0, 0, -PROBE_TIP_M).applyMatrix4(hand.ray.matrixWorld));
      send({ type: "probe", action: "place", tip_mm: tip.toArray().map((x) => x * 1000) });
      headset.lastProbe = now;
      headset.sent.probe += 1;
    } else if (!pressed && hand.pressed) {
      send({ type: "probe", action: "lift" });
    }
    hand.pressed = pressed;
  }

  function ream(now, s, hand, value, analog) {
    const r = s.reaming;
    if (s.tools.Reamer?.source !== "tracker" && now - headset.lastAim > SEND_EVERY_MS) {
      // the shaft: the ray's +z (back toward the hand), in the scene's frame
      view.root.updateMatrixWorld();
      AXIS.setFromMatrixColumn(hand.ray.matrixWorld, 2).transformDirection(INVERSE.copy(view.root.matrixWorld).invert());
      if (!headset.aim || headset.aim.angleTo(AXIS) > AIM_STEP_RAD) {
        headset.aim = AXIS.clone();
        send({ type: "reamer_axis", axis: AXIS.toArray() });
        headset.sent.aim += 1;
      }
      headset.lastAim = now;
    }
    const pressed = value > PRESSED;
    if (r.force_source !== "sensor") {
      // the trigger's pressure scales the trainer's largest push; a hand's pinch pushes the trainer's usual push
      const defaults = stats.hello.defaults;
      const push = Math.round(analog ? value * defaults.max_force_n : pressed ? defaults.force_n : 0);
      if (headset.push === undefined || Math.abs(push - headset.push) >= PUSH_STEP_N || (push === 0) !== (headset.push === 0)) {
        send({ type: "force", newton: push });
        headset.push = push;
        headset.sent.push += 1;
      }
    }
    if (pressed !== hand.pressed && r.available && pressed !== r.running) send({ type: "run", action: pressed ? "start" : "pause" });
    hand.pressed = pressed;
  }

  function frame(now) {
    const s = stats.last;
    headset.frames += 1;
    place(s);
    if (s) {
      useControllers(now, s);
      headset.panels.score.show(scoreLines(s, tool));
      headset.panels.status.show(statusLines(s, tool));
      view.animate();
    }
    const started = performance.now();
    renderer.render(view.scene, view.camera);
    if (headset.timing.measure) {
      const gl = renderer.getContext();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4)); // waits for the drawing to finish
      headset.timing.drawMs.push(performance.now() - started);
      headset.timing.calls = renderer.info.render.calls;
      headset.timing.triangles = renderer.info.render.triangles;
    }
  }

  headset.lastProbe = headset.lastAim = -Infinity;
  return headset;
}
