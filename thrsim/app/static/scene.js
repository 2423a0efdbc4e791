// The navigation scene: a stylised pelvis built from the server's landmarks, the IR camera and
// its truncated-pyramid tracking volume, the tracked tools and the reamer's safe-zone ray.
// Coordinates are the server's model frame (metres, +x patient right, +y anterior, +z superior),
// used as three.js's world as it is: the patient lies supine, anterior is up (three.js's +y).
// Under software WebGL (SwiftShader) a frame's CPU cost grows with its draw calls (~25 µs each),
// its triangles (~0.35 µs) and, most of all, the pixels it rasterises: parts that share a material
// are merged into one geometry (coloured per vertex where their colours differ; not instanced, as
// SwiftShader draws each instance as a draw of its own), spheres and tubes have no more segments
// than their size on screen needs, closed shapes are drawn front faces only, the table's grid has
// few lines (each crosses the screen), and the canvas's resolution follows the frame rate
// (render_scale.js).
import * as THREE from "three";
import { mergeGeometries } from "three/addons/utils/BufferGeometryUtils.js";
import { RenderScale, imageRendering } from "./render_scale.js";

// The pelvis's bars are closed tubes, drawn front faces only; its plates (the iliac wings) are
// open, seen from both sides. SwiftShader rasterises every back face it is given: the bars drawn
// double-sided cost it about 2 of its 9 ms a frame at 1280×720.
const BONE_BARS = new THREE.MeshLambertMaterial({ color: 0xe6d8b8 });
const BONE_PLATES = new THREE.MeshLambertMaterial({ color: 0xe6d8b8, side: THREE.DoubleSide });
const GREEN = 0x00c850, RED = 0xdc1e1e, AMBER = 0xffb000, GREY = 0x888888, YELLOW = 0xffe14d;
export const ZONE_COLOURS = { green: GREEN, amber: AMBER, red: RED };

// Scratch objects reused by the per-state and per-frame updates.
const SPIN = new THREE.Matrix4();
const POSE = new THREE.Matrix4();
const SCALE = new THREE.Matrix4();
const COLOUR = new THREE.Color();

const v = (p) => new THREE.Vector3(p[0], p[1], p[2]);
const mirror = (p) => [-p[0], p[1], p[2]];

function matrixFromRowMajor(values, into = POSE) {
  return into.set(...values);
}

// One geometry from parts (uv dropped: no material here is textured; every part indexed, as
// mergeGeometries needs them all alike).
function merge(parts) {
  for (const part of parts) {
    part.deleteAttribute("uv");
    if (!part.index) part.setIndex([...Array(part.attributes.position.count).keys()]);
  }
  return mergeGeometries(parts);
}

// A part of a merged mesh drawn with vertex colours (three.js reads them as linear, as
// Color.setHex gives them).
function painted(geometry, hex) {
  const c = new THREE.Color(hex);
  const colours = new Float32Array(geometry.attributes.position.count * 3);
  for (let i = 0; i < colours.length; i += 3) c.toArray(colours, i);
  geometry.setAttribute("color", new THREE.BufferAttribute(colours, 3));
  return geometry;
}

// A bar along the points: a tube closed at both ends by flat caps on its own end rings (whose
// vertex order turns clockwise seen from ahead of the curve), so its back faces need no drawing.
function bar(points, radius, radial = 8) {
  const curve = new THREE.CatmullRomCurve3(points.map(v));
  const tube = new THREE.TubeGeometry(curve, 12, radius, radial, false);
  const p = tube.attributes.position;
  const ring = (first) => Array.from({ length: radial }, (_, j) => [p.getX(first + j), p.getY(first + j), p.getZ(first + j)]);
  const start = fan(curve.getPointAt(0).toArray(), ring(0));
  const end = fan(curve.getPointAt(1).toArray(), ring(p.count - radial - 1).reverse());
  return [tube, start, end];
}

function fan(centre, loop) {
  // A triangle fan from a centre point to a closed loop: a thin bony plate.
  const positions = [];
  for (let i = 0; i < loop.length; i++) {
    const a = loop[i], b = loop[(i + 1) % loop.length];
    positions.push(...centre, ...a, ...b);
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(positions, 3));
  geometry.computeVertexNormals();
  return geometry;
}

function hemisphereCup(centre, axis, radius) {
  // The acetabulum: a hemispherical socket opening along `axis`.
  const geometry = new THREE.SphereGeometry(radius, 16, 6, 0, Math.PI * 2, 0, Math.PI / 2);
  geometry.applyQuaternion(new THREE.Quaternion().setFromUnitVectors(new THREE.Vector3(0, 1, 0), v(axis).negate().normalize()));
  return geometry.translate(...centre);
}

function buildPelvis(scene) {
  const group = new THREE.Group();
  const bars = [], plates = [], cups = [];
  const lm = scene.landmarks;
  const side = scene.side, other = side === "right" ? "left" : "right";
  const rimNames = Object.keys(lm).filter((n) => n.startsWith("rim_"));
  const rimCentre = rimNames.reduce((s, n) => s.add(v(lm[n])), new THREE.Vector3()).multiplyScalar(1 / rimNames.length);
  const rimAxis = new THREE.Vector3().subVectors(rimCentre, v(scene.acetabulum[side])).normalize();
  for (const s of [side, other]) {
    const flip = s === side ? (p) => p : mirror;
    const get = (name) => (lm[`${name}_${s}`] ?? flip(lm[name]));
    const acetabulum = scene.acetabulum[s];
    const axis = s === side ? rimAxis.toArray() : mirror(rimAxis.toArray());
    const ischialSpine = flip(lm.ischial_spine), tuberosity = flip(lm.ischial_tuberosity);
    const notch = [0.55 * ischialSpine[0] + 0.45 * get("psis")[0], -0.13, 0.5 * (ischialSpine[2] + get("psis")[2]) + 0.02];
    const crest = [get("asis"), get("iliac_tubercle"), get("iliac_crest_posterior"), get("psis")];
    const wingLoop = [...crest, notch, [acetabulum[0] * 0.9, acetabulum[1] - 0.01, acetabulum[2] + 0.035], get("aiis")];
    const wingCentre = wingLoop.reduce((a, p) => a.map((x, k) => x + p[k] / wingLoop.length), [0, 0, 0]);
    wingCentre[0] *= 0.8; // the iliac fossa curves medially
    plates.push(fan(wingCentre, wingLoop));
    bars.push(...bar(crest, 0.007));
    bars.push(...bar([acetabulum, get("pubic"), [0.0, flip(lm.pubic_symphysis)[1], flip(lm.pubic_symphysis)[2]]], 0.009));
    bars.push(...bar([get("pubic"), [get("pubic")[0] * 1.3, -0.03, -0.11], tuberosity], 0.007));
    bars.push(...bar([acetabulum, ischialSpine, tuberosity], 0.01));
    cups.push(hemisphereCup(acetabulum, axis, scene.rim_radius_m));
    bars.push(...bar([get("psis"), [get("psis")[0] * 0.35, -0.16, 0.0], [0, -0.14, -0.06]], 0.012)); // sacrum edge
  }
  group.add(new THREE.Mesh(merge(bars), BONE_BARS), new THREE.Mesh(merge(plates), BONE_PLATES));
  const sockets = new THREE.Mesh(merge(cups), new THREE.MeshLambertMaterial({ color: 0xc9b48a, side: THREE.DoubleSide }));
  sockets.name = "sockets"; // the reaming page hides them: its bone patch is the operated socket
  group.add(sockets);
  return group;
}

// The marker balls, one mesh: they always share a colour (green tracked, red not).
function markerBalls(markers, radius = 0.0065) {
  const material = new THREE.MeshLambertMaterial({ color: GREEN });
  const balls = merge(markers.map((m) => new THREE.SphereGeometry(radius, 8, 6).translate(...m)));
  return { balls: new THREE.Mesh(balls, material), material };
}

function plate() {
  return painted(new THREE.BoxGeometry(0.07, 0.1, 0.004).translate(0, 0, -0.004), 0x505a66);
}

function rod(from, to, radius, color) {
  const a = v(from), b = v(to);
  const geometry = new THREE.CylinderGeometry(radius, radius, a.distanceTo(b), 10);
  geometry.applyQuaternion(new THREE.Quaternion().setFromUnitVectors(new THREE.Vector3(0, 1, 0), b.clone().sub(a).normalize()));
  return painted(geometry.translate(...a.add(b).multiplyScalar(0.5).toArray()), color);
}

function buildTool(name, scene) {
  const group = new THREE.Group();
  group.matrixAutoUpdate = false;
  const { balls, material } = markerBalls(scene.tool_markers[name]);
  group.add(balls);
  const tip = scene.tool_tips[name];
  const extras = { pose: new THREE.Matrix4() };
  // Plate, shaft and head: fixed colours, one mesh. DoubleSide for the open reamer head; the
  // closed plate and shaft hide their own back faces.
  const body = [plate()];
  if (name === "Probe") {
    body.push(rod([0, 0, 0], tip, 0.003, 0xb0b8c0));
  } else if (name === "Reamer") {
    body.push(rod([0, 0, 0], tip, 0.005, 0xb0b8c0));
    const radius = scene.reamer_head_diameter_m / 2;
    const head = new THREE.SphereGeometry(radius, 16, 6, 0, Math.PI * 2, 0, Math.PI / 2);
    head.applyQuaternion(new THREE.Quaternion().setFromUnitVectors(new THREE.Vector3(0, 1, 0), new THREE.Vector3(0, 0, -1))); // dome into the bone (−z)
    body.push(painted(head.translate(...tip), 0xc0c6cc));
    // The ray: the reamer axis through the head centre, coloured by the safe zone.
    const ray = new THREE.Mesh(new THREE.CylinderGeometry(0.0025, 0.0025, 0.5, 8), new THREE.MeshBasicMaterial({ color: GREY }));
    ray.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), new THREE.Vector3(0, 0, 1));
    ray.position.set(tip[0], tip[1], tip[2] + 0.08);
    group.add(ray);
    extras.ray = ray;
  }
  group.add(new THREE.Mesh(merge(body), new THREE.MeshLambertMaterial({ vertexColors: true, side: name === "Reamer" ? THREE.DoubleSide : THREE.FrontSide })));
  return { group, material, ...extras };
}

function buildCamera(volume) {
  // Camera frame: +z along the view, x right, y down; the volume is a truncated pyramid.
  const group = new THREE.Group();
  group.matrixAutoUpdate = false;
  const body = new THREE.Mesh(new THREE.BoxGeometry(0.5, 0.07, 0.08), new THREE.MeshLambertMaterial({ color: 0x30363d }));
  group.add(body);
  const lenses = [-0.22, 0.22].map((x) => new THREE.CylinderGeometry(0.03, 0.03, 0.02, 20).rotateX(Math.PI / 2).translate(x, 0, 0.045));
  group.add(new THREE.Mesh(merge(lenses), new THREE.MeshLambertMaterial({ color: 0x7030a0, emissive: 0x300050 })));
  const n = volume.near_mm / 1e3, f = volume.far_mm / 1e3;
  const nw = volume.near_half_width_mm / 1e3, nh = volume.near_half_height_mm / 1e3;
  const fw = volume.far_half_width_mm / 1e3, fh = volume.far_half_height_mm / 1e3;
  const corners = [
    [-nw, -nh, n], [nw, -nh, n], [nw, nh, n], [-nw, nh, n],
    [-fw, -fh, f], [fw, -fh, f], [fw, fh, f], [-fw, fh, f],
  ];
  // Edges only: translucent faces covering half the screen cost software renderers most of their
  // frame time, and the edges read as the pyramid just as well.
  const volumeGroup = new THREE.Group();
  const edges = [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]];
  const lines = new THREE.BufferGeometry();
  lines.setAttribute("position", new THREE.Float32BufferAttribute(edges.flatMap(([a, b]) => [...corners[a], ...corners[b]]), 3));
  volumeGroup.add(new THREE.LineSegments(lines, new THREE.LineBasicMaterial({ color: 0x6fa8ff })));
  const sight = new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(0, 0, 0), new THREE.Vector3(0, 0, n)]);
  volumeGroup.add(new THREE.Line(sight, new THREE.LineDashedMaterial({ color: 0x6fa8ff, dashSize: 0.05, gapSize: 0.03 })));
  group.add(volumeGroup);
  return { group, volumeGroup };
}

export class NavigationScene {
  constructor(canvas) {
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: false, powerPreference: "high-performance" });
    this.renderScale = RenderScale.fromQuery(location.search);
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x1b2026);
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.01, 20);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x404040, 1.6));
    const sun = new THREE.DirectionalLight(0xffffff, 1.4);
    sun.position.set(1, 2, 1.5);
    this.scene.add(sun);
    this.root = new THREE.Group();
    this.scene.add(this.root);
    const grid = new THREE.GridHelper(4, 20, 0x3a434d, 0x2b323a); // the operating table's plane, 20 cm squares
    grid.position.y = -0.2;
    this.scene.add(grid);
    this.content = null;
  }

  resize(width, height) {
    this.size = [width, height];
    const ratio = Math.min(window.devicePixelRatio, 1.5) * this.renderScale.scale;
    this.renderer.setPixelRatio(ratio);
    this.renderer.setSize(width, height, false);
    this.renderer.domElement.style.imageRendering = imageRendering(ratio);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
  }

  // Once per animation frame, before drawing, with whether the page draws in it: true when the
  // render scale changed (the canvas was resized, so cleared: the page draws in this frame).
  pace(now, draws) {
    if (!this.renderScale.frame(now, draws)) return false;
    this.resize(...this.size);
    return true;
  }

  build(scene) {
    if (this.content) this.root.remove(this.content);
    this.content = new THREE.Group();
    this.root.add(this.content);
    this.sceneInfo = scene;
    this.content.add(buildPelvis(scene));
    // The landmark points: one mesh coloured per vertex (grey, green once acquired), and the point
    // to touch next drawn over its own ball, larger, glowing and pulsing.
    const ball = new THREE.SphereGeometry(0.004, 8, 6);
    this.landmarkNames = Object.keys(scene.landmarks);
    this.ballVertices = ball.attributes.position.count;
    const balls = this.landmarkNames.map((name) => painted(ball.clone().translate(...scene.landmarks[name]), GREY));
    this.landmarks = new THREE.Mesh(merge(balls), new THREE.MeshLambertMaterial({ vertexColors: true }));
    this.content.add(this.landmarks);
    this.landmarkLook = "";
    this.nextLandmark = new THREE.Mesh(ball, new THREE.MeshLambertMaterial({ color: YELLOW, emissive: 0x806000 }));
    this.nextLandmark.visible = false;
    this.content.add(this.nextLandmark);
    const target = new THREE.Mesh(new THREE.PlaneGeometry(0.08, 0.08), new THREE.MeshLambertMaterial({ color: 0xf0f0f0, side: THREE.DoubleSide }));
    target.position.copy(v(scene.calibration_target));
    this.content.add(target);
    const pattern = new THREE.Mesh(new THREE.PlaneGeometry(0.04, 0.04), new THREE.MeshBasicMaterial({ color: 0x202020, side: THREE.DoubleSide }));
    pattern.position.copy(v(scene.calibration_target)).add(new THREE.Vector3(0, 0, 0.001));
    this.content.add(pattern);
    const ir = buildCamera(scene.volume);
    this.irCamera = ir.group;
    this.volume = ir.volumeGroup;
    this.content.add(this.irCamera);
    this.tools = {};
    for (const name of Object.keys(scene.tool_markers)) {
      const tool = buildTool(name, scene);
      this.tools[name] = tool;
      this.content.add(tool.group);
    }
    this.occluder = new THREE.Mesh(new THREE.BoxGeometry(1, 1, 1), new THREE.MeshLambertMaterial({ color: 0xd9a07a, transparent: true, opacity: 0.85 }));
    this.occluder.matrixAutoUpdate = false;
    this.occluder.visible = false;
    this.content.add(this.occluder);
    this.focus = v(scene.acetabulum[scene.side]);
  }

  irCameraPosition() { return new THREE.Vector3().setFromMatrixPosition(this.irCamera.matrix); }

  setVolumeVisible(visible) { if (this.volume) this.volume.visible = visible; }

  apply(state) {
    if (!this.tools) return;
    matrixFromRowMajor(state.camera.pose, this.irCamera.matrix);
    for (const [name, tool] of Object.entries(this.tools)) {
      const info = state.tools[name];
      tool.group.visible = info.pose !== null;
      if (info.pose) tool.group.matrix.copy(matrixFromRowMajor(info.pose, tool.pose));
      tool.material.color.setHex(info.tracked ? GREEN : RED);
    }
    const ray = this.tools.Reamer.ray;
    ray.material.color.setHex(state.zone ? ZONE_COLOURS[state.zone.colour] : GREY);
    this.occluder.visible = state.occluder.boxes.length > 0;
    if (this.occluder.visible) {
      const box = state.occluder.boxes[0];
      matrixFromRowMajor(box.pose, this.occluder.matrix).multiply(SCALE.makeScale(...box.size));
    }
    this.registration = state.registration;
  }

  // Per drawn frame: the landmark to touch next pulses; acquired ones are green (colours are
  // rewritten only when the registration changed).
  animate() {
    const reg = this.registration;
    if (!reg || !this.landmarks) return;
    const look = `${reg.current} ${reg.acquired.join(" ")}`;
    if (look !== this.landmarkLook) {
      this.landmarkLook = look;
      const colours = this.landmarks.geometry.attributes.color;
      this.landmarkNames.forEach((name, i) => {
        COLOUR.setHex(reg.acquired.includes(name) ? GREEN : GREY);
        for (let k = i * this.ballVertices; k < (i + 1) * this.ballVertices; k++) colours.setXYZ(k, COLOUR.r, COLOUR.g, COLOUR.b);
      });
      colours.needsUpdate = true;
      const i = this.landmarkNames.indexOf(reg.current);
      this.nextLandmark.visible = i >= 0;
      if (i >= 0) {
        this.nextLandmark.position.fromArray(this.sceneInfo.landmarks[reg.current]);
        this.nextLandmark.material.color.setHex(reg.acquired.includes(reg.current) ? GREEN : YELLOW);
      }
    }
    if (this.nextLandmark.visible) this.nextLandmark.scale.setScalar(1.6 * (1 + 0.5 * Math.abs(Math.sin(performance.now() / 200))));
  }

  // Whether a landmark waits to be touched (it pulses).
  pulsing() { return this.registration?.current != null; }

  // Turns the reamer about its own axis (tool z) from its last pose: the reaming page's running
  // reamer, and a scene that changes every frame for measuring drawing speed (?continuous=1).
  spinReamer(angle) {
    const reamer = this.tools?.Reamer;
    if (reamer) reamer.group.matrix.copy(reamer.pose).multiply(SPIN.makeRotationZ(angle));
  }

  // The display's pose in the model frame, row-major (sent for the calibration step).
  viewerPose() {
    this.camera.updateMatrixWorld();
    this.root.updateMatrixWorld();
    const inModel = this.root.matrixWorld.clone().invert().multiply(this.camera.matrixWorld);
    return inModel.clone().transpose().toArray();
  }

  render() { this.renderer.render(this.scene, this.camera); }
}
