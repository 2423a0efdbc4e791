// The reaming trainer page: connects to /ws/reaming, draws the pelvis, the reamer and the bone
// as it is removed (binary frames of what changed), and sends the run, force and aim controls.
// The server owns the session, the simulator and the recording; this page only shows and asks.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { BonePatch, parseMesh } from "./bone.js";
import { CavityView } from "./cavity.js";
import { $, askTrainee, commonMessage, connectMode, setText, showAngles, showHello, showTools, toast } from "./page.js";
import { NavigationScene, cameraViews } from "./scene.js";
import { attachHeadset } from "./xr.js";

const canvas = $("view");
const view = new NavigationScene(canvas);
const orbit = new OrbitControls(view.camera, canvas);
orbit.enableDamping = false;

// Figures the end-to-end tests and the benchmark read.
const stats = { frames: 0, states: 0, boneFrames: 0, boneBytes: 0, errors: [], acks: [], events: [], last: null, hello: null, saved: null, connected: false, visibleFaces: 0, removed: 0 };
// Latency probe (`thrsim bench --reaming-page`): when the measured inclination changes, when that
// state arrived and when it was first drawn (performance.now(), ms).
stats.probe = { inclination: null, arrived: 0, drawn: 0 };
// Drawn-bone lag (`thrsim bench --reaming-page`): at each drawing while reaming, how long (ms,
// wall-clock) the page has known of a change to the bone newer than the bone it draws: since the
// first state whose bone changed past the drawn bone's frame arrived, 0 when the bone drawn is the
// latest (the worst, their sum and count). newerFrames: [frame of the change, arrival], oldest first.
stats.boneLag = { worst: 0, sum: 0, count: 0 };
const newerFrames = [];
let bone = null;
const cavityView = new CavityView(view, stats);
window.trainer = { stats, view, cavityView, send: (message) => send(message), bone: () => bone };
view.onLoaded = cavityView.onChange = () => { dirty = inset.stale = true; };
view.onError = (error) => { stats.errors.push(String(error)); toast(error.message, "error"); };
// The surgeon looks down the planned cup's axis (the safe zone's centre until a plan says otherwise).
cameraViews(view, orbit, () => {
  const plan = stats.last?.reaming.plan;
  return plan ? { centre: plan.centre_m, axis: plan.axis } : { centre: view.sceneInfo.acetabulum[view.sceneInfo.side], axis: view.socketAxis() };
});

// The aim and the push: the server's (the hello's defaults) when a session starts, then the trainee's.
let steer = null;
let force = null;
let maxForce = null;
let running = false;
let dirty = true;
let hudStale = false;
let pendingBone = [];

function resize() { view.resize(window.innerWidth, window.innerHeight); dirty = true; }
window.addEventListener("resize", resize);
resize();

// Bone frames are decompressed asynchronously: each step on the bone waits for the one before it.
let boneApplied = Promise.resolve();

function onBone(step) {
  boneApplied = boneApplied.then(step).catch((error) => { stats.errors.push(String(error)); toast(`bone frame: ${error.message}`, "error"); });
}

// Frames that arrive while one is being applied wait in the patch's backlog and are applied
// together by the next step, so the drawn bone catches up at once instead of one frame a draw.
function applyBone(patch, buffer) {
  patch.backlog ??= [];
  patch.backlog.push(buffer);
  if (patch.backlog.length > 1) return; // the step already chained takes this frame too
  onBone(async () => {
    const buffers = patch.backlog.splice(0);
    await patch.apply(...buffers);
    stats.boneFrames += buffers.length;
    stats.visibleFaces = patch.visibleFaces;
    stats.removed = patch.removedCount();
    dirty = inset.stale = true;
  });
}

function receiveBone(buffer) {
  stats.boneBytes += buffer.byteLength;
  if (bone) applyBone(bone, buffer);
  else pendingBone.push(buffer);  // the mesh is still on its way
}

async function loadBone(scene) {
  const info = scene.reaming;
  if (!info.available) {
    $("unavailable").textContent = `Reaming is unavailable: ${info.unavailable}`;
    $("unavailable").classList.remove("hidden");
    return;
  }
  $("unavailable").classList.add("hidden");
  const previous = bone;
  const response = await fetch(info.mesh);
  if (!response.ok) { toast(`bone mesh: ${response.status}`, "error"); return; }
  const patch = new BonePatch(parseMesh(await response.arrayBuffer()), info.patch_to_model);
  patch.object.layers.enable(1); // also in the cavity inset
  view.openSocket(patch.mesh.positions, patch.object); // the pelvis gives way to the bone being reamed
  cavityView.setBone(patch);
  view.scene.traverse((object) => { if (object.isLight) object.layers.enable(1); });
  // The server sends each viewer only what changed since what it last sent: a rebuilt patch (the
  // other hip, a new session) starts from the levels this page holds once the frames before it are applied.
  if (previous && previous.levels.length === patch.levels.length) {
    onBone(() => {
      patch.levels.set(previous.levels);
      patch.frame = previous.frame;
      patch.rebuild();
      dirty = inset.stale = true;
    });
  }
  bone = patch;
  view.content.add(patch.object);
  for (const buffer of pendingBone.splice(0)) applyBone(patch, buffer);
  dirty = inset.stale = true;
}

function translucentReamer() {
  // The reamer's head sits in the cavity: seen through, the bone under it stays visible.
  const reamer = view.tools?.Reamer;
  if (!reamer) return;
  reamer.group.traverse((part) => {
    if (part.isMesh && part !== reamer.ray && part.material.vertexColors) {
      part.material.transparent = true;
      part.material.opacity = 0.3;
      part.material.depthWrite = false;
      part.material.side = THREE.FrontSide; // blending both faces of the long shaft cost ~5 ms a frame in SwiftShader
    }
  });
}

function receive(message) {
  if (message.type === "state") {
    stats.states += 1;
    stats.last = message;
    const lastSeen = newerFrames.length ? newerFrames[newerFrames.length - 1][0] : -1;
    const changed = message.reaming.bone_frame; // the frame of the bone's last change (frames that change nothing need no drawing)
    if (changed > lastSeen) newerFrames.push([changed, performance.now()]);
    else if (changed < lastSeen) newerFrames.length = 0; // an undo or a restore: the frames start again
    const inclination = message.angles ? message.angles.radiographic[0] : null;
    if (inclination !== stats.probe.inclination) stats.probe = { inclination, arrived: performance.now(), drawn: 0 };
    view.apply(message);
    placeReamer(message.reaming);
    cavityView.apply(message);
    if (!stats.framed && bone) frameView();
    running = message.reaming.running;
    hudStale = true; // the panel's text follows at the next drawn frame: states come up to twice a tick
    for (const e of message.reaming.events) feedback(e);
    dirty = true;
  } else if (message.type === "hello" || message.type === "scene") {
    if (message.type === "hello") {
      showHello(message, stats);
      if (message.role === "trainee") askTrainee(send);
      if (document.visibilityState !== "visible") sendVisibility(); // a session that starts while the page is hidden holds too
      steer = { ...message.defaults.reamer };
      planEdited = false; // a new session: its plan
      forces.torqueScale = 0;
      force = message.defaults.force_n;
      maxForce = message.defaults.max_force_n;
      $("force").max = maxForce;
    }
    view.build(message.scene);
    for (const span of document.querySelectorAll(".warning-mm")) span.textContent = message.scene.reaming.warning_mm; // the help's words: the server's threshold
    translucentReamer();
    // No registration here: the landmark points would only clutter the rim.
    view.landmarks.visible = false;
    view.nextLandmark.visible = false;
    view.pulsing = () => false;
    $("side").value = message.scene.side;
    stats.framed = false;
    loadBone(message.scene);
    // A new session starts from the server's aim and push, the other hip from the page's: sent either way.
    sendSteer();
    sendForce();
  } else {
    commonMessage(message, stats);
  }
}

// The reamer head follows the simulated centre (it advances as bone goes): the tool's pose is the
// steered or tracked one, moved along its axis to where the simulation has it.
function placeReamer(reaming) {
  const reamer = view.tools?.Reamer;
  if (!reamer || !reaming.reamer_centre || !view.sceneInfo) return;
  const tip = view.sceneInfo.tool_tips.Reamer;
  const m = reamer.group.matrix.elements;
  const headNow = [0, 1, 2].map((i) => m[i] * tip[0] + m[4 + i] * tip[1] + m[8 + i] * tip[2] + m[12 + i]);
  for (let i = 0; i < 3; i++) m[12 + i] += reaming.reamer_centre[i] - headNow[i];
}

function feedback(event) {
  stats.events.push(event.kind);
  const text = {
    start: "reaming", pause: "paused", restore: "bone restored (the report keeps what went before)",
    undo: `undone: ${event.detail} (the report keeps what went before)`, side_changed: `${event.detail} hip`,
    push_out_of_range: `push ${event.detail}`, feed_out_of_range: `feed: ${event.detail}`,
    tilt_out_of_range: `tilt ${event.detail}`, reamer_out_of_range: `reamer ${event.detail}`,
    centre_out_of_range: `centre: ${event.detail}`, contact_out_of_range: `contact: ${event.detail}`,
    medial_wall_breached: `medial wall breached: ${event.detail}`,
    plan_set: `plan set: ${event.detail}`, reamer_changed: `reamer ${event.detail}`,
    cup_confirmed: `cup orientation confirmed at ${event.detail} (the report measures it against the plan)`,
    perforated: event.face === "cut_edge" ? `the modelled bone ended: ${event.detail}` : `perforated: the reamer broke through the bone; ${event.detail}`,
    passed_through: `perforated: the reamer went through the bone, none left in its path; ${event.detail}`,
    cancellous_reached: `cancellous bone: ${event.detail}`,
  }[event.kind];
  const bad = ["perforated", "passed_through", "medial_wall_breached", "push_out_of_range", "feed_out_of_range", "tilt_out_of_range", "reamer_out_of_range", "centre_out_of_range", "contact_out_of_range"]
    .includes(event.kind);
  if (text) toast(text, event.kind === "start" ? "good" : bad ? "error" : "");
}

function showState(s) {
  const r = s.reaming;
  showAngles(s);
  setText("removed-volume", `${r.removed_volume_mm3.toFixed(1)} mm³ (${r.removed} elements)`);
  setText("depth", `${r.depth_mm.toFixed(2)} mm`);
  setText("push", `${r.force_n.toFixed(0)} N (${r.force_source})`);
  setText("sim-time", `${r.time_s.toFixed(1)} s` + (r.behind_frames ? ` · ${r.behind_frames} frames behind` : "") + (r.paused ? ` · paused (${r.paused})` : ""));
  setText("step-ms", r.step_ms === null ? "—" : `${r.step_ms.toFixed(1)} ms per frame`);
  setText("note", r.note || (s.zone ? s.note : ""));
  showPlanAndReamer(r);
  showForces(r);
  running = r.running;
  setText("run", running ? "Pause reaming" : "Start reaming");
  showTools(s.tools);
}

// The bone's reaction along the shaft and the motor's torque, where the simulator predicts them (a
// whole-socket model): numbers and bars, the reaction's against the most a hand pushes with the push
// marked (a reaction above the push holds the reamer), the torque's against the most seen this session.
// What the simulator is given outside what it learned is said beneath.
const forces = { seen: false, torqueScale: 0 };
function showForces(r) {
  const known = r.reaction_n !== null;
  if (known && !forces.seen) { forces.seen = true; for (const row of document.querySelectorAll(".force-row")) row.classList.remove("hidden"); }
  if (forces.seen) {
    const fraction = (x, scale) => `${(100 * clamp(scale > 0 ? x / scale : 0, 0, 1)).toFixed(1)}%`;
    setText("reaction", known ? `${r.reaction_n.toFixed(0)} N` : "—");
    setText("torque", known ? `${r.motor_torque_n_m.toFixed(2)} N·m` : "—");
    if (known) forces.torqueScale = Math.max(forces.torqueScale, r.motor_torque_n_m);
    $("reaction-bar").style.width = fraction(known ? r.reaction_n : 0, maxForce);
    $("torque-bar").style.width = fraction(known ? r.motor_torque_n_m : 0, forces.torqueScale);
    $("push-mark").style.left = fraction(r.force_n, maxForce);
  }
  const outside = r.out_of_range.length ? `Outside what the simulator learned: ${r.out_of_range.join(", ")}` : "";
  setText("out-of-range", outside);
  $("out-of-range").classList.toggle("hidden", !outside);
}

// The plan's fields follow the session's plan until the trainee edits them; once reaming has
// started (or an instructor's case file set it) the plan is fixed and its fields locked.
let planEdited = false;
const PLAN_FIELDS = { "plan-cup": "cup_diameter_mm", "plan-inc": "inclination_deg", "plan-ant": "anteversion_deg", "plan-med": "medialisation_mm", "plan-sup": "superior_shift_mm" };

function showPlanAndReamer(r) {
  const p = r.plan;
  const locked = p.fixed || stats.role === "observer";
  for (const [id, key] of Object.entries(PLAN_FIELDS)) {
    if (!planEdited) $(id).value = p[key];
    $(id).disabled = locked;
  }
  $("plan-set").disabled = locked;
  setText("plan-status", p.source === "case file" ? "Set by the instructor's case file." : p.fixed ? "Fixed: reaming has started." : "Set before reaming: the report measures the cavity against it.");
  const patient = view.sceneInfo?.reaming.bone === "socket" ? ` · a ${p.native_socket_mm} mm socket, ${p.cancellous} bone` : "";
  setText("plan-summary", `${p.cup_diameter_mm} mm cup · ${p.inclination_deg}° / ${p.anteversion_deg}° · centre ${p.medialisation_mm} mm medial, ${p.superior_shift_mm} mm superior${patient}`);
  const select = $("reamer-size");
  if (select.options.length !== r.reamer.sizes_mm.length) select.replaceChildren(...r.reamer.sizes_mm.map((size) => new Option(`${size} mm`, size)));
  if (document.activeElement !== select) select.value = r.reamer.size_mm;
  setText("reamer", `${r.reamer.size_mm} mm`);
  setText("reamer-note", r.reamer.note);
}

function sendPlan() {
  const plan = { type: "plan" };
  for (const [id, key] of Object.entries(PLAN_FIELDS)) plan[key] = Number($(id).value);
  planEdited = false;
  send(plan);
}

function swapReamer(step) {
  const reamer = stats.last?.reaming.reamer;
  if (!reamer) return;
  const sizes = reamer.sizes_mm, at = sizes.indexOf(reamer.size_mm);
  const size = sizes[clamp(at + step, 0, sizes.length - 1)];
  if (size !== reamer.size_mm) send({ type: "reamer_size", size_mm: size });
}

function frameView() {
  stats.framed = true;
  inset.stale = true;
  // The main view: the hip from outside, 35° off the acetabulum's opening (the patch's +z, the
  // safe zone's centre) toward the feet, the reamer and its ray in view.
  const p = view.sceneInfo.reaming.patch_to_model;
  opening.set(p[2], p[6], p[10]).normalize();
  const aside = new THREE.Vector3().crossVectors(opening, new THREE.Vector3(0, 0, 1)).cross(opening).normalize().negate();
  const eye = opening.clone().multiplyScalar(Math.cos(0.61)).add(aside.multiplyScalar(Math.sin(0.61))).multiplyScalar(0.27);
  view.camera.position.copy(view.focus).add(eye);
  orbit.target.copy(view.focus);
  orbit.update();
  view.setHome(view.camera.position, orbit.target);
  // The inset: the cavity seen along the opening, the bone alone (layer 1). The patch lies in the
  // socket's floor, an inner radius (22 mm) in from the acetabular centre: seen from 6 cm off it. The
  // whole socket is seen whole: its rim (the larger of the native socket and the planned cup, and a
  // few millimetres) fills the inset's field.
  const floor = view.focus.clone().addScaledVector(opening, -0.022);
  const plan = stats.last?.reaming.plan;
  const rim = plan ? Math.max(plan.cup_diameter_mm, plan.native_socket_mm) / 2e3 + 0.003 : 0.027;
  const away = view.sceneInfo.reaming.bone === "socket" ? rim / Math.tan(THREE.MathUtils.degToRad(cavity.fov / 2)) : 0.06 - 0.022;
  cavity.position.copy(view.focus).addScaledVector(opening, away);
  cavity.up.set(0, 0, 1);
  cavity.lookAt(floor);
}

// Close-up of the cavity in the lower right corner: it shows what the reamer hides in the main view.
// It holds the bone alone, so it is drawn into a texture only when the bone, its camera or its size
// changed, at most every INSET_REFRESH_MS while the bone changes, and that texture is copied into
// the corner every frame (the turning reamer redraws the main view 60 times a second; drawing the
// patch's 5,500 faces again for the inset cost SwiftShader ~4 ms of a frame's 9 at half scale).
const opening = new THREE.Vector3();
const cavity = new THREE.PerspectiveCamera(18, 1, 0.005, 1);
cavity.layers.set(1);
const INSET = 0.36; // of the window's height
const INSET_REFRESH_MS = 100;
const inset = { target: null, pixels: 0, stale: true, drawnAt: -Infinity, placement: new THREE.Matrix4() };
const insetQuad = new THREE.Mesh(new THREE.PlaneGeometry(2, 2), new THREE.MeshBasicMaterial({ depthTest: false, depthWrite: false, toneMapped: false }));
const insetScene = new THREE.Scene().add(insetQuad);
const insetCamera = new THREE.OrthographicCamera(-1, 1, 1, -1, 0, 1);

function drawInset(renderer, size) {
  const pixels = Math.max(1, Math.round(size * renderer.getPixelRatio()));
  if (inset.pixels !== pixels) {
    inset.target?.dispose();
    inset.target = new THREE.WebGLRenderTarget(pixels, pixels);
    inset.target.texture.colorSpace = THREE.SRGBColorSpace; // stored as the canvas would show it
    insetQuad.material.map = inset.target.texture;
    insetQuad.material.needsUpdate = true;
    inset.pixels = pixels;
    inset.stale = true;
  }
  if (!inset.placement.equals(bone.object.matrixWorld)) { // the patch moved in the world (a new scene)
    inset.placement.copy(bone.object.matrixWorld);
    inset.stale = true;
  }
  const now = performance.now();
  if (inset.stale && now - inset.drawnAt < INSET_REFRESH_MS) {
    dirty = true; // drawn again soon, so the last change reaches the inset
  } else if (inset.stale) {
    renderer.setRenderTarget(inset.target);
    renderer.render(view.scene, cavity);
    renderer.setRenderTarget(null);
    inset.stale = false;
    inset.drawnAt = now;
  }
  renderer.setScissorTest(true);
  renderer.setViewport(window.innerWidth - size - 8, 8, size, size);
  renderer.setScissor(window.innerWidth - size - 8, 8, size, size);
  renderer.render(insetScene, insetCamera);
  renderer.setScissorTest(false);
}

function render() {
  if (view.renderer.xr.isPresenting) return; // in a headset, xr.js draws
  const renderer = view.renderer;
  const width = window.innerWidth, height = window.innerHeight;
  renderer.setScissorTest(false);
  renderer.setViewport(0, 0, width, height);
  view.render();
  if (bone && stats.framed) drawInset(renderer, Math.round(INSET * height));
}

// ---- controls ---------------------------------------------------------------------------------

function sendSteer() {
  $("steer-inc").value = steer.inclination_deg;
  $("steer-ant").value = steer.anteversion_deg;
  $("steer-inc-value").textContent = `${steer.inclination_deg}°`;
  $("steer-ant-value").textContent = `${steer.anteversion_deg}°`;
  send({ type: "reamer", ...steer });
}
function sendForce() {
  $("force").value = force;
  $("force-value").textContent = `${force} N`;
  send({ type: "force", newton: force });
}
$("steer-inc").addEventListener("input", (e) => { steer.inclination_deg = Number(e.target.value); sendSteer(); });
$("steer-ant").addEventListener("input", (e) => { steer.anteversion_deg = Number(e.target.value); sendSteer(); });
$("force").addEventListener("input", (e) => { force = Number(e.target.value); sendForce(); });
$("run").addEventListener("click", () => send({ type: "run", action: running ? "pause" : "start" }));
$("undo").addEventListener("click", () => send({ type: "run", action: "undo" }));
$("confirm-cup").addEventListener("click", () => send({ type: "confirm_cup" }));
// Restoring the bone loses the cavity: the page asks first.
$("reset").addEventListener("click", () => $("confirm-restore").showModal());
$("confirm-restore").addEventListener("close", () => { if ($("confirm-restore").returnValue === "restore") send({ type: "run", action: "reset" }); });
$("end").addEventListener("click", () => { $("end").disabled = true; send({ type: "end_session" }); }); // again once the server answers
// Hiding or leaving the page pauses reaming: the server holds this session's simulator while the
// page is hidden, and a running reamer goes on when it shows again.
const sendVisibility = () => send({ type: "page", visible: document.visibilityState === "visible" });
document.addEventListener("visibilitychange", sendVisibility);
$("side").addEventListener("change", (e) => send({ type: "side", value: e.target.value }));
$("reamer-size").addEventListener("change", (e) => send({ type: "reamer_size", size_mm: Number(e.target.value) }));
for (const id of Object.keys(PLAN_FIELDS)) $(id).addEventListener("input", () => { planEdited = true; });
$("plan-set").addEventListener("click", sendPlan);
$("help-toggle").addEventListener("click", () => $("help").classList.toggle("hidden"));
$("help-close").addEventListener("click", () => $("help").classList.add("hidden"));

const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));
document.addEventListener("keydown", (e) => {
  if (e.target instanceof HTMLInputElement) return; // a slider's arrows or a plan field's typing
  if (e.target instanceof HTMLSelectElement) return;
  if (document.querySelector("dialog[open]")) return; // a question on screen: keys answer it, not the trainer
  if (!steer) return; // before the hello: nothing to steer yet
  const step = e.shiftKey ? 5 : 1;
  const handled = {
    " ": () => $("run").click(),
    u: () => $("undo").click(),
    Backspace: () => $("undo").click(),
    r: () => $("reset").click(),
    "+": () => { force = clamp(force + 10, 0, maxForce); sendForce(); },
    "=": () => { force = clamp(force + 10, 0, maxForce); sendForce(); },
    "-": () => { force = clamp(force - 10, 0, maxForce); sendForce(); },
    ArrowUp: () => { steer.inclination_deg = clamp(steer.inclination_deg + step, 0, 90); sendSteer(); },
    ArrowDown: () => { steer.inclination_deg = clamp(steer.inclination_deg - step, 0, 90); sendSteer(); },
    ArrowRight: () => { steer.anteversion_deg = clamp(steer.anteversion_deg + step, -90, 90); sendSteer(); },
    ArrowLeft: () => { steer.anteversion_deg = clamp(steer.anteversion_deg - step, -90, 90); sendSteer(); },
    Enter: () => $("confirm-cup").click(),
    "[": () => swapReamer(-1),
    "]": () => swapReamer(1),
    h: () => $("help").classList.toggle("hidden"),
  }[e.key.length === 1 ? e.key.toLowerCase() : e.key];
  if (handled) { e.preventDefault(); handled(); }
});

// Draw when something changed (a state, a bone frame, the view moved) and, while reaming, every
// display frame: the reamer turns, as a running reamer does, at 2 turns a second (the simulated
// 136 rad/s, 22 turns a second, would alias to a random-looking jitter at 60 frames a second).
const SPIN_RAD_PER_MS = (2 * Math.PI * 2) / 1000;
orbit.addEventListener("change", () => { dirty = true; });
function frame(now) {
  const draw = view.pace(now, dirty || running) || dirty || running; // a resized canvas is cleared: drawn again
  if (draw) {
    dirty = false;
    stats.frames += 1;
    if (running && stats.last) {
      view.spinReamer(now * SPIN_RAD_PER_MS);
      placeReamer(stats.last.reaming);
    }
    render();
    if (running && bone && bone.frame >= 0) {
      while (newerFrames.length && newerFrames[0][0] <= bone.frame) newerFrames.shift();
      const lag = newerFrames.length ? performance.now() - newerFrames[0][1] : 0;
      stats.boneLag.worst = Math.max(stats.boneLag.worst, lag);
      stats.boneLag.sum += lag;
      stats.boneLag.count += 1;
    }
    if (hudStale) { hudStale = false; showState(stats.last); }
    if (stats.probe.arrived && !stats.probe.drawn) stats.probe.drawn = performance.now();
  }
  requestAnimationFrame(frame);
}
requestAnimationFrame(frame);
// The page sends its aim and push when the hello (or a new scene) arrives.
const send = connectMode("reaming", stats, { onText: receive, onBinary: receiveBone });
attachHeadset(view, stats, send, "reamer"); // a controller is the reamer in a headset (xr.js)
