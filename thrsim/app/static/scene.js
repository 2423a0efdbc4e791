// The navigation scene: the pelvis's bone surface (built by the server around its landmarks), the
// IR camera and its truncated-pyramid tracking volume, the tracked tools and the reamer's safe-zone
// ray; camera views (home, surgeon's eye) both pages share.
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

const GREEN = 0x00c850, RED = 0xdc1e1e, AMBER = 0xffb000, GREY = 0x888888, YELLOW = 0xffe14d;
export const ZONE_COLOURS = { green: GREEN, amber: AMBER, red: RED };

// Scratch objects reused by the per-state and per-frame updates.
const SPIN = new THREE.Matrix4();
const POSE = new THREE.Matrix4();
const SCALE = new THREE.Matrix4();
const COLOUR = new THREE.Color();

const v = (p) => new THREE.Vector3(p[0], p[1], p[2]);

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

// The pelvis: its bone surface is built by the server (thrsim.nav.pelvis_surface, GET /api/pelvis:
// "THRP", u32 version, vertices, triangles, then positions and normals (V×3 f32, metres, model
// frame) and triangles (T×3 u32)), fetched once per page. Closed and outward-facing, so drawn front
// faces only. It costs SwiftShader more of a frame than the rest of the scene together: it is lit as
// a Lambert surface by the scene's fixed lights, but shaded once per vertex on the CPU (shadePelvis)
// and drawn unlit with those colours. The bone the reaming page serves (a patch of the socket's
// floor, or the whole socket) replaces the pelvis where it lies: fragments of the pelvis inside the
// served bone's extent (its radii and its half-angle about its pole, in its own frame) are
// discarded, so the reamed bone is never hidden behind the pelvis's own socket surface; only the
// triangles near that extent are drawn with the discarding shader (a discard costs every fragment it
// may apply to), the rest with a plain one.
export function parsePelvis(buffer) {
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== "THRP") throw new Error(`not a thrsim pelvis surface (${magic})`);
  const header = new DataView(buffer);
  const vertices = header.getUint32(8, true), triangles = header.getUint32(12, true);
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array(buffer, 16, 3 * vertices), 3));
  geometry.setAttribute("normal", new THREE.BufferAttribute(new Float32Array(buffer, 16 + 12 * vertices, 3 * vertices), 3));
  geometry.setIndex(new THREE.BufferAttribute(new Uint32Array(buffer, 16 + 24 * vertices, 3 * triangles), 1));
  return geometry;
}

let pelvisSurface = null;
function fetchPelvis(url) {
  pelvisSurface ??= fetch(url).then((response) => {
    if (!response.ok) throw new Error(`pelvis surface: ${response.status}`);
    return response.arrayBuffer();
  }).then(parsePelvis);
  return pelvisSurface;
}

// The pelvis's two materials, both unlit with the shaded vertex colours: [far from the served bone,
// near it (discarding what lies inside it)].
function pelvisMaterials() {
  const discarding = new THREE.MeshBasicMaterial({ vertexColors: true });
  const served = { boneFromModel: { value: new THREE.Matrix4() }, boneExtent: { value: new THREE.Vector4(0, 0, 2, 0) } };
  discarding.userData.served = served;
  discarding.onBeforeCompile = (shader) => {
    Object.assign(shader.uniforms, served);
    shader.vertexShader = shader.vertexShader
      .replace("#include <common>", "#include <common>\nuniform mat4 boneFromModel;\nvarying vec3 vBonePoint;")
      .replace("#include <begin_vertex>", "#include <begin_vertex>\nvBonePoint = (boneFromModel * vec4(transformed, 1.0)).xyz;");
    // boneExtent: inner and outer radius (mm), cosine of the half-angle about −z, on (1) or off (0)
    shader.fragmentShader = shader.fragmentShader
      .replace("#include <common>", "#include <common>\nuniform vec4 boneExtent;\nvarying vec3 vBonePoint;")
      .replace("#include <clipping_planes_fragment>", `#include <clipping_planes_fragment>
        float servedRadius = length(vBonePoint);
        if (boneExtent.w > 0.5 && servedRadius > boneExtent.x && servedRadius < boneExtent.y && -vBonePoint.z >= boneExtent.z * servedRadius) discard;`);
  };
  return [new THREE.MeshBasicMaterial({ vertexColors: true }), discarding];
}

const PELVIS_COLOUR = new THREE.Color(0xe6d8b8);
const LIGHT = new THREE.Vector3();
const TARGET = new THREE.Vector3();
const NORMAL = new THREE.Vector3();
const TO_LOCAL = new THREE.Matrix3();

// The pelvis's vertex colours (linear): three.js's Lambert shading of PELVIS_COLOUR under the
// scene's hemisphere and directional lights (the diffuse colour over π times the irradiance), at
// each vertex's normal, the lights' directions taken into the pelvis's own frame.
function shadePelvis(mesh, lights) {
  const normals = mesh.geometry.attributes.normal;
  const colours = mesh.geometry.attributes.color ?? new THREE.BufferAttribute(new Float32Array(normals.count * 3), 3);
  TO_LOCAL.setFromMatrix4(mesh.matrixWorld).invert();
  const directions = lights.map((light) => {
    LIGHT.setFromMatrixPosition(light.matrixWorld);
    if (light.isDirectionalLight) LIGHT.sub(TARGET.setFromMatrixPosition(light.target.matrixWorld));
    return LIGHT.applyMatrix3(TO_LOCAL).normalize().toArray();
  });
  for (let i = 0; i < normals.count; i++) {
    NORMAL.fromBufferAttribute(normals, i);
    let r = 0, g = 0, b = 0;
    lights.forEach((light, k) => {
      const [x, y, z] = directions[k];
      const cosine = NORMAL.x * x + NORMAL.y * y + NORMAL.z * z;
      if (light.isHemisphereLight) {
        const w = 0.5 * cosine + 0.5, sky = light.color, ground = light.groundColor;
        r += light.intensity * (ground.r + (sky.r - ground.r) * w);
        g += light.intensity * (ground.g + (sky.g - ground.g) * w);
        b += light.intensity * (ground.b + (sky.b - ground.b) * w);
      } else {
        const irradiance = light.intensity * Math.max(0, cosine);
        r += irradiance * light.color.r;
        g += irradiance * light.color.g;
        b += irradiance * light.color.b;
      }
    });
    colours.setXYZ(i, (PELVIS_COLOUR.r * r) / Math.PI, (PELVIS_COLOUR.g * g) / Math.PI, (PELVIS_COLOUR.b * b) / Math.PI);
  }
  mesh.geometry.setAttribute("color", colours);
  colours.needsUpdate = true;
}

// Splits the pelvis's triangles into two draws: those with a corner within `reachMm` of the served
// bone's origin (`boneFromModel` maps the model frame to the bone's, mm) last, drawn with the
// discarding material; the rest first, drawn plain. Without a served bone, all are drawn plain.
function splitPelvis(geometry, boneFromModel = null, reachMm = 0) {
  const index = geometry.index.array, positions = geometry.attributes.position;
  const far = [], near = [];
  const point = new THREE.Vector3();
  for (let t = 0; t < index.length; t += 3) {
    let close = false;
    for (let c = 0; c < 3 && boneFromModel; c++) close ||= point.fromBufferAttribute(positions, index[t + c]).applyMatrix4(boneFromModel).length() < reachMm;
    (close ? near : far).push(index[t], index[t + 1], index[t + 2]);
  }
  index.set(far);
  index.set(near, far.length);
  geometry.index.needsUpdate = true;
  geometry.clearGroups();
  geometry.addGroup(0, far.length, 0);
  geometry.addGroup(far.length, near.length, 1);
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
    const sun = new THREE.DirectionalLight(0xffffff, 1.4);
    sun.position.set(1, 2, 1.5);
    this.lights = [new THREE.HemisphereLight(0xffffff, 0x404040, 1.6), sun];
    this.scene.add(...this.lights);
    // The pelvis is shaded again when it moves against the lights (a headset places the scene).
    const shaded = { placement: new THREE.Matrix4(), geometry: null };
    this.scene.onBeforeRender = () => {
      const pelvis = this.pelvis;
      if (!pelvis?.geometry.index || (shaded.geometry === pelvis.geometry && shaded.placement.equals(pelvis.matrixWorld))) return;
      shadePelvis(pelvis, this.lights);
      shaded.geometry = pelvis.geometry;
      shaded.placement.copy(pelvis.matrixWorld);
    };
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
    this.pelvis = new THREE.Mesh(new THREE.BufferGeometry(), this.pelvis?.material ?? pelvisMaterials());
    this.pelvis.name = "pelvis";
    this.content.add(this.pelvis);
    const pelvis = this.pelvis;
    fetchPelvis(scene.pelvis).then((geometry) => {
      pelvis.geometry = geometry;
      this.splitPelvis();
      this.onLoaded?.();
    }).catch((error) => this.onError?.(error));
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

  // Where the served bone lies (its mesh's nodes, mm in its own frame, placed by `object`, whose
  // matrix maps that frame to the model frame): the pelvis is not drawn there.
  openSocket(nodesMm, object) {
    let inner = Infinity, outer = 0, cosine = 1;
    for (let i = 0; i < nodesMm.length; i += 3) {
      const x = nodesMm[i], y = nodesMm[i + 1], z = nodesMm[i + 2];
      const r = Math.hypot(x, y, z);
      inner = Math.min(inner, r);
      outer = Math.max(outer, r);
      if (r > 0) cosine = Math.min(cosine, -z / r);
    }
    const served = this.servedExtent();
    served.boneFromModel.value.copy(object.matrix).invert();
    // radially, a margin of the pelvis's own facets (its grid is 8 mm: its socket lies within about 1 mm
    // of a sphere); around, a little inside the bone's edge, so that the pelvis's socket meets it with no gap
    served.boneExtent.value.set(inner - 1.5, outer + 1.5, Math.cos(Math.max(0, Math.acos(cosine) - 0.01)), 1);
    this.splitPelvis();
  }

  // The discarding material's uniforms: the served bone's frame and extent.
  servedExtent() { return this.pelvis.material[1].userData.served; }

  // The pelvis's triangles near the served bone drawn apart (splitPelvis): those with a corner
  // within the bone's outer radius and two of the pelvis's facets (8 mm each) of its origin.
  splitPelvis() {
    if (!this.pelvis.geometry.index) return; // still on its way: split when it arrives
    const served = this.servedExtent();
    const on = served.boneExtent.value.w > 0.5;
    splitPelvis(this.pelvis.geometry, on ? served.boneFromModel.value : null, served.boneExtent.value.y + 16);
  }

  // Camera views: the page's home view (set when it frames the scene), and looking down an axis
  // at a point, as a surgeon looks into the socket (a little off the axis, past the reamer's shaft).
  setHome(position, target) {
    this.home = { position: position.clone(), target: target.clone() };
  }

  resetView(orbit) {
    if (!this.home) return;
    this.camera.position.copy(this.home.position);
    orbit.target.copy(this.home.target);
    orbit.update();
  }

  surgeonView(orbit, centre, axis, distance = 0.22) {
    const out = v(axis).normalize();
    const up = new THREE.Vector3(0, 0, 1).addScaledVector(out, -out.z).normalize(); // superior, across the axis
    const eye = out.clone().multiplyScalar(Math.cos(0.3)).addScaledVector(up, Math.sin(0.3)).multiplyScalar(distance);
    this.camera.up.copy(up);
    this.camera.position.copy(v(centre)).add(eye);
    orbit.target.copy(v(centre));
    orbit.update();
    this.camera.up.set(0, 1, 0);
  }

  // The operated socket's opening: from its centre toward the rim landmarks' centre (model frame).
  socketAxis() {
    const lm = this.sceneInfo.landmarks;
    const rim = Object.keys(lm).filter((n) => n.startsWith("rim_"));
    const mean = rim.reduce((s, n) => s.add(v(lm[n])), new THREE.Vector3()).multiplyScalar(1 / rim.length);
    const centre = v(this.sceneInfo.acetabulum[this.sceneInfo.side]);
    // the rim's landmarks lie on a circle about the axis: its normal is the cross of two chords
    const a = v(lm[rim[0]]).sub(mean), b = v(lm[rim[Math.floor(rim.length / 4)]]).sub(mean);
    const normal = new THREE.Vector3().crossVectors(a, b).normalize();
    const outward = new THREE.Vector3().subVectors(centre, v(this.sceneInfo.landmarks[`asis_${this.sceneInfo.side === "right" ? "left" : "right"}`]));
    return (normal.dot(outward) < 0 ? normal.negate() : normal).toArray();
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

  // The flat view (in a headset, xr.js draws each eye instead).
  render() {
    if (!this.renderer.xr.isPresenting) this.renderer.render(this.scene, this.camera);
  }
}

// The camera-view buttons (reset, surgeon's eye) and their keys (Home, E), on either page.
// `socket()` gives the surgeon's view its target: { centre, axis } in the model frame.
export function cameraViews(view, orbit, socket) {
  const bar = document.createElement("div");
  bar.id = "camera-views";
  const button = (id, text, key, title, action) => {
    const b = document.createElement("button");
    b.id = id;
    b.title = title;
    const kbd = document.createElement("kbd");
    kbd.textContent = key;
    b.append(`${text} `, kbd);
    b.addEventListener("click", action);
    bar.append(b);
  };
  const reset = () => view.resetView(orbit);
  const surgeon = () => {
    const { centre, axis } = socket();
    view.surgeonView(orbit, centre, axis);
  };
  button("view-reset", "Reset view", "Home", "Back to the starting view (Home)", reset);
  button("view-surgeon", "Surgeon's view", "E", "Look down the socket's axis, as the surgeon does (E)", surgeon);
  document.body.append(bar);
  document.addEventListener("keydown", (e) => {
    if ((e.target instanceof HTMLInputElement && e.target.type === "range") || e.target instanceof HTMLSelectElement) return;
    if (e.ctrlKey || e.metaKey || e.altKey) return;
    if (e.key === "Home") { e.preventDefault(); reset(); }
    if (e.key === "e" || e.key === "E") { e.preventDefault(); surgeon(); }
  });
}
