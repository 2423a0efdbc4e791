// The navigation trainer page: connects to /ws/navigation, draws each state, sends controls.
// The server owns the session (and records it); this page only shows and asks.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { $, askTrainee, commonMessage, connectMode, setText, showAngles, showHello, showTools, toast } from "./page.js";
import { NavigationScene, cameraViews } from "./scene.js";
import { attachHeadset } from "./xr.js";

const canvas = $("view");
const view = new NavigationScene(canvas);
const orbit = new OrbitControls(view.camera, canvas);
orbit.enableDamping = false;
view.onLoaded = () => { dirty = true; }; // the pelvis's surface arrived
view.onError = (error) => { stats.errors.push(String(error)); toast(error.message, "error"); };
cameraViews(view, orbit, () => ({ centre: view.sceneInfo.acetabulum[view.sceneInfo.side], axis: view.socketAxis() }));

// Figures the end-to-end tests and the benchmark read.
const stats = { frames: 0, states: 0, errors: [], acks: [], events: [], last: null, hello: null, saved: null, connected: false };
window.trainer = { stats, view, send: (message) => send(message), screenOf: (name) => screenOf(view.sceneInfo.landmarks[name]), millimetrePixels: () => millimetrePixels(), probeTip: () => probeTip };

let state = null;
let steer = null; // the reamer's aim: the server's starting aim (the hello's defaults), then the trainee's
let camera = { azimuth_deg: 50, elevation_deg: -37, distance_mm: 1600 };
let audio = null;

function resize() {
  view.resize(window.innerWidth, window.innerHeight);
}
window.addEventListener("resize", resize);
resize();

function beep(frequency, duration = 0.12) {
  if (!$("sound").checked) return;
  try {
    audio = audio || new AudioContext();
    const oscillator = audio.createOscillator();
    const gain = audio.createGain();
    oscillator.frequency.value = frequency;
    gain.gain.value = 0.08;
    oscillator.connect(gain).connect(audio.destination);
    oscillator.start();
    oscillator.stop(audio.currentTime + duration);
  } catch (error) {
    // No audio device (a headless browser): feedback stays visual.
  }
}

function receive(message) {
  if (message.type === "state") {
    stats.states += 1;
    stats.last = message;
    state = message;
    const look = JSON.stringify([message.tools, message.camera, message.zone, message.registration, message.occluder]);
    if (look !== lastLook) { lastLook = look; dirty = true; }
    view.apply(message);
    if (!stats.framed) frameView();
    showState(message);
    for (const e of message.events) feedback(e);
  } else if (message.type === "hello") {
    showHello(message, stats);
    if (message.role === "trainee") askTrainee(send);
    probeTip = null; // a new session: the probe is not in the hand yet
    view.build(message.scene);
    $("side").value = message.scene.side;
    steer = { ...message.defaults.reamer }; // a new session starts from the server's aim: so does the page
    sendSteer();
  } else if (message.type === "scene") {
    view.build(message.scene);
    $("side").value = message.scene.side;
    sendSteer(); // the other hip: keep the page's aim
  } else {
    commonMessage(message, stats);
  }
}

function feedback(event) {
  stats.events.push(event.kind);
  if (event.kind === "acquired") {
    beep(880);
    toast(`acquired ${plainName(event.landmark)}: ${(event.value * 1000).toFixed(1)} mm from the landmark`, "good");
  } else if (event.kind === "completed") {
    beep(660, 0.1); setTimeout(() => beep(990, 0.2), 120);
  } else if (event.kind === "app_built") {
    toast(`pelvis registered: angles are now measured on this patient (fit error ${event.detail})`, "good");
  } else if (event.kind === "tracking_lost") {
    beep(220, 0.2);
    toast(`tracking lost: ${event.detail}`, "error");
  } else if (event.kind === "calibration_done") {
    toast(`display calibrated: ${event.detail}`, "good");
  } else if (event.kind === "calibration_refused") {
    toast(`calibration refused: ${event.detail}`, "error");
  } else if (event.kind === "cup_confirmed") {
    toast(`cup orientation confirmed: ${event.detail}`, "good");
  }
}

function showState(s) {
  showAngles(s);
  setText("note", s.zone ? s.note : "");
  showTools(s.tools);
  const reg = s.registration;
  setText("reg-count", `${reg.acquired.length} / ${reg.total}`);
  const bar = `${(100 * reg.acquired.length) / reg.total}%`;
  if ($("reg-bar").style.width !== bar) $("reg-bar").style.width = bar;
  setText("reg-target", reg.done ? `done · fit error ${reg.rms_mm.toFixed(2)} mm` : reg.current ? plainName(reg.current) : "—");
  const cal = s.calibration;
  setText("calibration-status",
    cal.state === "sampling" ? `sampling ${cal.samples} / ${cal.needed} — hold still` :
    cal.state === "done" ? `residual ${cal.result.rotation_residual_rms_deg.toFixed(2)}° / ${cal.result.translation_residual_rms_mm.toFixed(1)} mm (${cal.result.used} samples)` :
    cal.state === "refused" ? `refused: ${cal.message}` : "not calibrated");
  if (document.activeElement !== $("definition") && $("definition").value !== s.definition) $("definition").value = s.definition;
  // Follow the server's camera (another viewer may move it), but not over this viewer's own
  // recent edits that the server has not applied yet.
  if (s.camera.source === "page" && !draggingCamera && performance.now() - lastCameraEdit > 1000) {
    camera = { azimuth_deg: s.camera.azimuth_deg, elevation_deg: s.camera.elevation_deg, distance_mm: s.camera.distance_mm };
    for (const [id, value] of [["cam-azimuth", camera.azimuth_deg], ["cam-elevation", camera.elevation_deg], ["cam-distance", camera.distance_mm]]) {
      if (Number($(id).value) !== value) $(id).value = value;
    }
  }
  if ($("occluder").checked !== s.occluder.present) $("occluder").checked = s.occluder.present;
}

function frameView() {
  stats.framed = true;
  // Beside the table, above the hip, looking between the hip and the IR camera: both in view.
  const focus = view.focus.clone().lerp(view.irCameraPosition(), 0.12);
  view.camera.position.set(focus.x + 0.75, focus.y + 0.4, focus.z + 0.5);
  orbit.target.copy(focus);
  orbit.update();
  view.setHome(view.camera.position, orbit.target);
}

// ---- controls ---------------------------------------------------------------------------------

let draggingCamera = false;
let lastCameraEdit = -Infinity;
function sendCamera() { lastCameraEdit = performance.now(); send({ type: "camera", ...camera }); }
for (const [id, key] of [["cam-azimuth", "azimuth_deg"], ["cam-elevation", "elevation_deg"], ["cam-distance", "distance_mm"]]) {
  const input = $(id);
  input.addEventListener("pointerdown", () => { draggingCamera = true; });
  input.addEventListener("pointerup", () => { draggingCamera = false; });
  input.addEventListener("input", () => { camera[key] = Number(input.value); sendCamera(); });
}
function sendSteer() {
  $("steer-inc").value = steer.inclination_deg;
  $("steer-ant").value = steer.anteversion_deg;
  $("steer-inc-value").textContent = `${steer.inclination_deg}°`;
  $("steer-ant-value").textContent = `${steer.anteversion_deg}°`;
  send({ type: "reamer", ...steer });
}
$("steer-inc").addEventListener("input", (e) => { steer.inclination_deg = Number(e.target.value); sendSteer(); });
$("steer-ant").addEventListener("input", (e) => { steer.anteversion_deg = Number(e.target.value); sendSteer(); });

// ---- the probe without a tracker: the trainee puts its tip on each landmark ----------------------
// Drag (or click) from near the glowing landmark or the probe's tip: the tip follows the pointer over
// the bone at the landmark's depth (the plane through it facing the view). Arrow keys nudge it 1 mm
// (Shift: 5 mm) across the view; Space brings the probe to the bone near the next landmark. Held
// still for ½ s within 5 mm of it, the landmark is acquired: the report scores how close.
let probeTip = null; // where this page put the tip (scene frame, metres)
const PLACE_INTERVAL_MS = 30; // a drag sends at most ~30 positions a second
let lastPlaced = 0, trailingPlace = null;
const plainName = (name) => name.replaceAll("_", " ");
const registering = () => state && !state.registration.done && state.tools.Probe?.source !== "tracker";
const currentTarget = () => (state?.registration.current ? view.sceneInfo.landmarks[state.registration.current] : null);

function screenOf(point) {
  const p = new THREE.Vector3(...point).project(view.camera);
  return [((p.x + 1) / 2) * window.innerWidth, ((1 - p.y) / 2) * window.innerHeight];
}

// The pointer's point on the plane through `anchor` facing the view.
function pointerOnPlane(clientX, clientY, anchor) {
  const caster = new THREE.Raycaster();
  caster.setFromCamera(new THREE.Vector2((clientX / window.innerWidth) * 2 - 1, -(clientY / window.innerHeight) * 2 + 1), view.camera);
  const normal = view.camera.getWorldDirection(new THREE.Vector3());
  const hit = caster.ray.intersectPlane(new THREE.Plane().setFromNormalAndCoplanarPoint(normal, new THREE.Vector3(...anchor)), new THREE.Vector3());
  return hit ? hit.toArray() : null;
}

// Pixels one millimetre spans at the current landmark (how fine a drag can be).
function millimetrePixels() {
  const target = currentTarget();
  if (!target) return null;
  const right = new THREE.Vector3().setFromMatrixColumn(view.camera.matrixWorld, 0).multiplyScalar(0.001);
  const [x0, y0] = screenOf(target), [x1, y1] = screenOf([target[0] + right.x, target[1] + right.y, target[2] + right.z]);
  return Math.hypot(x1 - x0, y1 - y0);
}

// A drag's positions go at most every PLACE_INTERVAL_MS, the latest never dropped: one that comes
// sooner goes when the interval ends, so the server holds the tip where the hand rests, not where it passed.
function placeProbe(tip, force = false) {
  probeTip = tip;
  const now = performance.now();
  if (!force && now - lastPlaced < PLACE_INTERVAL_MS) {
    trailingPlace ??= setTimeout(() => { trailingPlace = null; if (probeTip) placeProbe(probeTip, true); }, PLACE_INTERVAL_MS - (now - lastPlaced));
    return;
  }
  clearTimeout(trailingPlace);
  trailingPlace = null;
  lastPlaced = now;
  send({ type: "probe", action: "place", tip_mm: tip.map((x) => x * 1000) });
}

// Across the view by (right, up) millimetres.
function nudgeProbe(right, up) {
  const r = new THREE.Vector3().setFromMatrixColumn(view.camera.matrixWorld, 0);
  const u = new THREE.Vector3().setFromMatrixColumn(view.camera.matrixWorld, 1);
  const tip = new THREE.Vector3(...probeTip).addScaledVector(r, right * 0.001).addScaledVector(u, up * 0.001);
  placeProbe(tip.toArray(), true);
}

// Space: the probe on the bone 6–10 mm from the next landmark, in a direction of chance across the view.
function approach() {
  const target = currentTarget();
  if (!target) return;
  probeTip = target;
  const angle = Math.random() * 2 * Math.PI, distance = 6 + 4 * Math.random();
  nudgeProbe(distance * Math.cos(angle), distance * Math.sin(angle));
}

let dragging = false;
canvas.addEventListener("pointerdown", (e) => {
  if (e.button !== 0 || !registering() || stats.role !== "trainee") return;
  const near = (point) => point && Math.hypot(...screenOf(point).map((v, k) => v - [e.clientX, e.clientY][k])) < 40;
  if (!near(currentTarget()) && !near(probeTip)) return; // elsewhere, a drag turns the view
  dragging = true;
  orbit.enabled = false;
  canvas.setPointerCapture(e.pointerId);
  const tip = pointerOnPlane(e.clientX, e.clientY, currentTarget() ?? probeTip);
  if (tip) placeProbe(tip, true);
});
canvas.addEventListener("pointermove", (e) => {
  if (!dragging) return;
  const tip = pointerOnPlane(e.clientX, e.clientY, currentTarget() ?? probeTip);
  if (tip) placeProbe(tip);
});
const endDrag = (e) => {
  if (!dragging) return;
  dragging = false;
  orbit.enabled = true;
  const tip = pointerOnPlane(e.clientX, e.clientY, currentTarget() ?? probeTip);
  if (tip) placeProbe(tip, true); // where the hand stopped
};
canvas.addEventListener("pointerup", endDrag);
canvas.addEventListener("pointercancel", endDrag);

$("touch").addEventListener("click", () => approach());
const lift = () => { probeTip = null; send({ type: "probe", action: "lift" }); }; // a trailing place then sends nothing
$("lift").addEventListener("click", lift);
$("retake").addEventListener("click", () => send({ type: "registration", action: "retake" }));
$("restart").addEventListener("click", () => send({ type: "registration", action: "restart" }));
$("confirm").addEventListener("click", () => send({ type: "confirm_cup" }));
$("calibrate").addEventListener("click", () => { sendViewer(); send({ type: "calibration", action: "start" }); });
$("end").addEventListener("click", () => { $("end").disabled = true; send({ type: "end_session" }); }); // again once the server answers
$("definition").addEventListener("change", (e) => send({ type: "definition", value: e.target.value }));
$("side").addEventListener("change", (e) => send({ type: "side", value: e.target.value }));
$("show-volume").addEventListener("change", (e) => { view.setVolumeVisible(e.target.checked); dirty = true; });
$("occluder").addEventListener("change", (e) => send({ type: "occluder", present: e.target.checked }));
$("help-toggle").addEventListener("click", () => $("help").classList.toggle("hidden"));
$("help-close").addEventListener("click", () => $("help").classList.add("hidden"));

let lastViewerSent = 0;
function sendViewer() { send({ type: "viewer", pose: view.viewerPose() }); lastViewerSent = performance.now(); }
orbit.addEventListener("change", () => { if (performance.now() - lastViewerSent > 100) sendViewer(); });

const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));
document.addEventListener("keydown", (e) => {
  if (e.target instanceof HTMLInputElement && e.target.type === "range") return;
  if (e.target instanceof HTMLSelectElement) return;
  if (document.querySelector("dialog[open]")) return; // a question on screen: keys answer it, not the trainer
  const step = e.shiftKey ? 5 : 1;
  if (!steer) return; // before the hello: nothing to steer yet
  const probing = registering() && probeTip !== null; // while registering, the arrows move the probe's tip
  const handled = {
    " ": () => approach(),
    Backspace: () => send({ type: "registration", action: "retake" }),
    l: lift,
    Enter: () => send({ type: "confirm_cup" }),
    ArrowUp: () => { if (probing) return nudgeProbe(0, step); steer.inclination_deg = clamp(steer.inclination_deg + step, 0, 90); sendSteer(); },
    ArrowDown: () => { if (probing) return nudgeProbe(0, -step); steer.inclination_deg = clamp(steer.inclination_deg - step, 0, 90); sendSteer(); },
    ArrowRight: () => { if (probing) return nudgeProbe(step, 0); steer.anteversion_deg = clamp(steer.anteversion_deg + step, -90, 90); sendSteer(); },
    ArrowLeft: () => { if (probing) return nudgeProbe(-step, 0); steer.anteversion_deg = clamp(steer.anteversion_deg - step, -90, 90); sendSteer(); },
    "[": () => { camera.azimuth_deg = ((camera.azimuth_deg - 5 + 540) % 360) - 180; sendCamera(); },
    "]": () => { camera.azimuth_deg = ((camera.azimuth_deg + 5 + 540) % 360) - 180; sendCamera(); },
    v: () => { $("show-volume").checked = !$("show-volume").checked; view.setVolumeVisible($("show-volume").checked); dirty = true; },
    o: () => send({ type: "occluder", present: !$("occluder").checked }),
    c: () => $("calibrate").click(),
    h: () => $("help").classList.toggle("hidden"),
  }[e.key.length === 1 ? e.key.toLowerCase() : e.key];
  if (handled) { e.preventDefault(); handled(); }
});

// Draw only when something changed (a new pose, the view moved) or, while a landmark waits to be
// touched, for its pulse (~12 Hz): a browser on a busy machine then leaves the CPU to the server.
// ?continuous=1 draws every frame and turns the reamer a little each time: `thrsim bench
// --browser` then counts frames of a tool moving on every one, as a tracked tool in use.
const continuous = new URLSearchParams(location.search).has("continuous");
let dirty = true;
let lastLook = "";
let lastPulse = 0;
orbit.addEventListener("change", () => { dirty = true; });
window.addEventListener("resize", () => { dirty = true; });
function frame(now) {
  const pulse = view.pulsing() && now - lastPulse > 80;
  let draw = continuous || dirty || pulse;
  if (view.pace(now, draw)) draw = true; // the canvas was resized, so cleared
  if (draw) {
    if (pulse) lastPulse = now;
    dirty = false;
    stats.frames += 1;
    if (continuous) view.spinReamer(stats.frames * 0.05);
    view.animate();
    view.render();
  }
  requestAnimationFrame(frame);
}
requestAnimationFrame(frame);
const send = connectMode("navigation", stats, { onText: receive, onOpen: () => sendViewer() });
attachHeadset(view, stats, send, "probe"); // a controller is the probe in a headset (xr.js)
