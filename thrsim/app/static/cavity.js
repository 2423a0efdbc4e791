// The cavity against the plan, on the reaming page: the planned hemisphere outlined (a wire
// hemisphere of the planned cup's size at its centre and orientation, drawn over the bone, in the
// main view and the inset), the bone coloured by depth against it (or by its layers) with a legend
// in mm and a scale beside the inset, the medial wall's closeness and the modelled bone's edge's, each
// with a warning before it (the thresholds are the server's: scene.reaming.warning_mm and caution_mm), and an
// optional sound cue (off by default) when a reamer leaves the subchondral plate for cancellous
// bone (the server's cancellous_reached event, once a reamer). It reads the state the server sends (reaming.plan: its
// cup_diameter_mm, centre_m and axis in the pelvis model frame; bone_left_mm, medial_wall_modelled, edge_left_mm, events); the page's own panels stay the page's.
import * as THREE from "three";
import { DEPTH_STOPS, LAYER_COLOURS, NATIVE_COLOUR } from "./bone.js";

const OUTLINE_COLOUR = 0xffffff;

const $ = (id) => document.getElementById(id);

// A CSS gradient of the depth stops over their range, left (or bottom) to right (or top).
function gradient(direction) {
  const [lo, hi] = [DEPTH_STOPS[0][0], DEPTH_STOPS[DEPTH_STOPS.length - 1][0]];
  return `linear-gradient(${direction}, ${DEPTH_STOPS.map(([x, hex]) => `${hex} ${(100 * (x - lo)) / (hi - lo)}%`).join(", ")})`;
}

const TICKS_MM = [-2, -1, 0, 1, 2];
const tickText = (x) => (x > 0 ? `+${x}` : x < 0 ? `−${-x}` : "0");

function element(tag, attributes = {}, ...children) {
  const node = document.createElement(tag);
  Object.assign(node, attributes);
  node.append(...children);
  return node;
}

// A wire hemisphere of unit radius opening along +z (the cup's rim at z = 0, its dome toward −z):
// the rim, two latitudes and six meridians.
function hemisphereLines() {
  const points = [];
  const ring = (polar, segments = 48) => {
    for (let i = 0; i < segments; i++) {
      for (const k of [i, i + 1]) {
        const phi = (2 * Math.PI * k) / segments;
        points.push(Math.sin(polar) * Math.cos(phi), Math.sin(polar) * Math.sin(phi), -Math.cos(polar));
      }
    }
  };
  for (const polar of [Math.PI / 2, Math.PI / 3, Math.PI / 6]) ring(polar);
  for (let m = 0; m < 6; m++) {
    const phi = (Math.PI * m) / 3;
    for (let i = 0; i < 12; i++) {
      for (const k of [i, i + 1]) {
        const polar = (Math.PI / 2) * (k / 12);
        points.push(Math.sin(polar) * Math.cos(phi), Math.sin(polar) * Math.sin(phi), -Math.cos(polar));
      }
    }
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(points, 3));
  return geometry;
}

export class CavityView {
  constructor(view, stats) {
    this.view = view;
    this.stats = stats;
    this.stats.cues = 0;
    this.stats.wallWarnings = 0;
    this.stats.edgeWarnings = 0;
    this.bone = null;
    this.planKey = "";
    this.audio = null;
    // Drawn over the bone (it lies inside the bone still to ream), last, in both views (layer 1: the inset).
    this.outline = new THREE.LineSegments(hemisphereLines(), new THREE.LineBasicMaterial({ color: OUTLINE_COLOUR, transparent: true, opacity: 0.7, depthTest: false }));
    this.outline.renderOrder = 10;
    this.outline.matrixAutoUpdate = false;
    this.outline.visible = false;
    this.outline.layers.enable(1);
    this.buildPanels();
  }

  buildPanels() {
    const ticks = (className) => element("div", { className }, ...TICKS_MM.map((x) => element("span", {}, tickText(x))));
    this.legend = element("div", { id: "cavity-legend", className: "legend" },
      element("div", { className: "legend-title", id: "legend-title" }, "Depth against the plan (mm)"),
      element("div", { id: "legend-depth" },
        element("div", { className: "bar", style: `background: ${gradient("to right")}` }),
        ticks("ticks"),
        element("div", { className: "ends muted" }, element("span", {}, "bone still to ream"), element("span", {}, "on plan"), element("span", {}, "beyond plan")),
        element("span", { className: "swatch-row muted" }, element("span", { className: "swatch", style: `background: ${NATIVE_COLOUR}` }), " bone no reamer touched, beyond the plan")),
      element("div", { id: "legend-layers", className: "hidden" },
        ...Object.entries(LAYER_COLOURS).map(([name, hex]) => element("span", { className: "swatch-row" }, element("span", { className: "swatch", style: `background: ${hex}` }), ` ${name} bone`))),
      element("label", {}, "Colour ", element("select", { id: "bone-colours" },
        element("option", { value: "depth" }, "depth against the plan"), element("option", { value: "layers" }, "bone layers"))),
      element("div", { id: "medial-wall", className: "muted" }, "Medial wall: —"),
      element("div", { id: "cut-edge", className: "muted hidden", title: "Where the simulated bone is cut off from the pelvis it continues into: not anatomy. Through it, the simulation ends as a perforation." }, "Edge of the modelled bone: —"),
      element("label", { className: "check" }, element("input", { type: "checkbox", id: "cue-sound" }), "Sound when the reamer reaches cancellous bone"));
    this.insetScale = element("div", { id: "inset-scale", className: "legend" },
      element("div", { className: "legend-title" }, "mm"),
      element("div", { className: "vbar", style: `background: ${gradient("to top")}` }),
      ticks("vticks"));
    this.warning = element("div", { id: "wall-warning", className: "hidden", role: "alert" });
    this.edgeWarning = element("div", { id: "edge-warning", className: "hidden", role: "alert" });
    document.body.append(this.legend, this.insetScale, this.warning, this.edgeWarning);
    $("bone-colours").addEventListener("change", (e) => this.showColours(e.target.value === "depth"));
  }

  showColours(depth) {
    $("legend-depth").classList.toggle("hidden", !depth);
    $("legend-layers").classList.toggle("hidden", depth);
    $("legend-title").textContent = depth ? "Depth against the plan (mm)" : "Bone layers";
    this.insetScale.classList.toggle("hidden", !depth);
    this.bone?.setDepthColours(depth);
    this.onChange?.();
  }

  // A new bone (a new session, the other hip): the outline goes with it into the scene.
  setBone(bone) {
    this.bone = bone;
    this.planKey = "";
    this.view.content.add(this.outline);
    bone.setDepthColours($("bone-colours").value === "depth");
  }

  // Each state: the plan (outline and depth colours follow it), the medial wall, the cue of cancellous bone reached.
  apply(state) {
    const r = state.reaming;
    const plan = r.plan;
    if (plan && this.bone) this.showPlan(plan);
    this.showWall(r.bone_left_mm, r.medial_wall_modelled);
    this.showEdge(r.edge_left_mm);
    if (r.events.some((e) => e.kind === "cancellous_reached")) this.cue();
  }

  showPlan(plan) {
    const key = JSON.stringify([plan.cup_diameter_mm, plan.centre_m, plan.axis, this.bone.object.matrix.elements]);
    if (key === this.planKey) return;
    this.planKey = key;
    const radius = plan.cup_diameter_mm / 2e3;
    const centre = new THREE.Vector3(...plan.centre_m);
    const turn = new THREE.Quaternion().setFromUnitVectors(new THREE.Vector3(0, 0, 1), new THREE.Vector3(...plan.axis).normalize());
    this.outline.matrix.compose(centre, turn, new THREE.Vector3(radius, radius, radius));
    this.outline.visible = true;
    // the depth colours measure from the plan's centre in the bone's own frame (mm)
    const inBone = centre.clone().applyMatrix4(this.bone.object.matrix.clone().invert());
    this.bone.setPlan(inBone.toArray(), plan.cup_diameter_mm / 2);
    this.onChange?.();
  }

  // The bone left under the reamer's teeth before it breaks through: the medial wall where the bone
  // has one; the bone patch has none (said plainly), only its far face, where it perforates.
  showWall(left, medialWall) {
    const box = $("medial-wall");
    const known = left !== null && left !== undefined;
    const text = medialWall
      ? `Medial wall: ${known ? `${left.toFixed(1)} mm of bone left` : "—"}`
      : `Medial wall: not modelled on the bone patch${known ? ` · ${left.toFixed(1)} mm of bone left before its far face` : ""}`;
    if (box.textContent !== text) box.textContent = text;
    const words = medialWall
      ? (left <= 0 ? "Medial wall reached: stop" : `Medial wall close: ${left?.toFixed(1)} mm of bone left`)
      : (left <= 0 ? "Through the bone: stop" : `About to break through the bone: ${left?.toFixed(1)} mm left`);
    if (this.warn(box, this.warning, known ? left : null, words)) this.stats.wallWarnings += 1;
  }

  // The bone left under the reamer's teeth before the edge of the modelled bone (the whole socket's
  // supported boundary, where the simulated bone is cut off: not anatomy); the bone patch's edge is
  // its far face, which the medial wall's line already gives.
  showEdge(left) {
    const box = $("cut-edge");
    const socket = this.view.sceneInfo?.reaming.bone === "socket";
    box.classList.toggle("hidden", !socket);
    const known = socket && left !== null && left !== undefined;
    const text = `Edge of the modelled bone: ${known ? `${left.toFixed(1)} mm of bone left` : "—"}`;
    if (box.textContent !== text) box.textContent = text;
    const words = left <= 0
      ? "Edge of the modelled bone reached: the simulated bone ends here"
      : `Edge of the modelled bone close: ${left?.toFixed(1)} mm left (the simulated bone is cut off there, not anatomy)`;
    if (this.warn(box, this.edgeWarning, known ? left : null, words)) this.stats.edgeWarnings += 1;
  }

  // One line's level (amber under the caution, red under the warning: the server's thresholds) and its
  // warning above the view, shown with ``words`` while red; true when the warning has just shown.
  warn(box, warning, left, words) {
    const limits = this.view.sceneInfo?.reaming ?? {};
    const level = left === null ? "" : left < limits.warning_mm ? "bad" : left < limits.caution_mm ? "caution" : "";
    if (box.dataset.level !== level) box.dataset.level = level;
    const shown = level === "bad";
    const appeared = shown && warning.classList.contains("hidden");
    warning.classList.toggle("hidden", !shown);
    if (shown && warning.textContent !== words) warning.textContent = words;
    return appeared;
  }

  // Through the subchondral plate: a short falling tone, when the trainee asked for sound.
  cue() {
    if (!$("cue-sound").checked) return;
    this.stats.cues += 1;
    try {
      this.audio = this.audio || new AudioContext();
      const oscillator = this.audio.createOscillator(), gain = this.audio.createGain();
      oscillator.frequency.setValueAtTime(660, this.audio.currentTime);
      oscillator.frequency.linearRampToValueAtTime(330, this.audio.currentTime + 0.25);
      gain.gain.value = 0.08;
      oscillator.connect(gain).connect(this.audio.destination);
      oscillator.start();
      oscillator.stop(this.audio.currentTime + 0.25);
    } catch (error) {
      // no audio device (a headless browser): the colours still show the layer
    }
  }
}
