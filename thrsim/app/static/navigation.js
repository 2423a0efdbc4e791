// The navigation trainer page: connects to /ws/navigation, draws each state, sends controls.
// The server owns the session (and records it); this page only shows and asks.
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { $, commonMessage, connectMode, setText, showAngles, showHello, showTools, toast } from "./page.js";
import { NavigationScene, cameraViews } from "./scene.js";

const canvas = $("view");
const view = new NavigationScene(canvas);
const orbit = new OrbitControls(view.camera, canvas);
orbit.enableDamping = false;
view.onLoaded = () => { dirty = true; }; // the pelvis's surface arrived
view.onError = (error) => { stats.errors.push(String(error)); toast(error.message, "error"); };
cameraViews(view, orbit, () => ({ centre: view.sceneInfo.acetabulum[view.sceneInfo.side], axis: view.socketAxis() }));

// Figures the end-to-end tests and the benchmark read.
const stats = { frames: 0, states: 0, errors: [], acks: [], events: [], last: null, hello: null, saved: null, connected: false };
window.trainer = { stats, view, send: (message) => send(message) };

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
    toast(`acquired ${event.landmark} (${(event.value * 1000).toFixed(1)} mm from target)`, "good");
  } else if (event.kind === "completed") {
    beep(660, 0.1); setTimeout(() => beep(990, 0.2), 120);
  } else if (event.kind === "app_built") {
    toast(`anterior pelvic plane built · fit ${event.detail}`, "good");
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
  setText("reg-target", reg.done ? `done · fit ${reg.rms_mm.toFixed(2)} mm` : reg.current ?? "—");
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

const touch = (landmark = null) => send({ type: "probe", action: "touch", landmark });
$("touch").addEventListener("click", () => touch());
$("lift").addEventListener("click", () => send({ type: "probe", action: "lift" }));
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

// Clicking a landmark point touches it with the probe (a click, not the end of an orbit drag).
let down = null;
canvas.addEventListener("pointerdown", (e) => { down = [e.clientX, e.clientY]; });
canvas.addEventListener("pointerup", (e) => {
  if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) return;
  const name = view.pick((e.clientX / window.innerWidth) * 2 - 1, -(e.clientY / window.innerHeight) * 2 + 1);
  if (name) touch(name);
});

let lastViewerSent = 0;
function sendViewer() { send({ type: "viewer", pose: view.viewerPose() }); lastViewerSent = performance.now(); }
orbit.addEventListener("change", () => { if (performance.now() - lastViewerSent > 100) sendViewer(); });

const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));
document.addEventListener("keydown", (e) => {
  if (e.target instanceof HTMLInputElement && e.target.type === "range") return;
  if (e.target instanceof HTMLSelectElement) return;
  const step = e.shiftKey ? 5 : 1;
  if (!steer) return; // before the hello: nothing to steer yet
  const handled = {
    " ": () => touch(),
    Backspace: () => send({ type: "registration", action: "retake" }),
    l: () => send({ type: "probe", action: "lift" }),
    Enter: () => send({ type: "confirm_cup" }),
    ArrowUp: () => { steer.inclination_deg = clamp(steer.inclination_deg + step, 0, 90); sendSteer(); },
    ArrowDown: () => { steer.inclination_deg = clamp(steer.inclination_deg - step, 0, 90); sendSteer(); },
    ArrowRight: () => { steer.anteversion_deg = clamp(steer.anteversion_deg + step, -90, 90); sendSteer(); },
    ArrowLeft: () => { steer.anteversion_deg = clamp(steer.anteversion_deg - step, -90, 90); sendSteer(); },
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
