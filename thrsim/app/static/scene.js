// The navigation scene: a stylised pelvis built from the server's landmarks, the IR camera and
// its truncated-pyramid tracking volume, the tracked tools and the reamer's safe-zone ray.
// Coordinates are the server's model frame (metres, +x patient right, +y anterior, +z superior),
// used as three.js's world as it is: the patient lies supine, anterior is up (three.js's +y).
import * as THREE from "three";

const BONE = new THREE.MeshLambertMaterial({ color: 0xe6d8b8, side: THREE.DoubleSide });
const GREEN = 0x00c850, RED = 0xdc1e1e, AMBER = 0xffb000, GREY = 0x888888, YELLOW = 0xffe14d;
export const ZONE_COLOURS = { green: GREEN, amber: AMBER, red: RED };

const SPIN = new THREE.Matrix4();

const v = (p) => new THREE.Vector3(p[0], p[1], p[2]);
const mirror = (p) => [-p[0], p[1], p[2]];

function matrixFromRowMajor(values) {
  const m = new THREE.Matrix4();
  m.set(...values);
  return m;
}

function tube(points, radius, material = BONE) {
  const curve = new THREE.CatmullRomCurve3(points.map(v));
  return new THREE.Mesh(new THREE.TubeGeometry(curve, 24, radius, 8, false), material);
}

function fan(centre, loop, material = BONE) {
  // A triangle fan from a centre point to a closed loop: a thin bony plate.
  const positions = [];
  for (let i = 0; i < loop.length; i++) {
    const a = loop[i], b = loop[(i + 1) % loop.length];
    positions.push(...centre, ...a, ...b);
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(positions, 3));
  geometry.computeVertexNormals();
  return new THREE.Mesh(geometry, material);
}

function hemisphereCup(centre, axis, radius) {
  // The acetabulum: a hemispherical socket opening along `axis`.
  const geometry = new THREE.SphereGeometry(radius, 24, 12, 0, Math.PI * 2, 0, Math.PI / 2);
  const cup = new THREE.Mesh(geometry, new THREE.MeshLambertMaterial({ color: 0xc9b48a, side: THREE.DoubleSide }));
  cup.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), v(axis).negate().normalize());
  cup.position.copy(v(centre));
  return cup;
}

function buildPelvis(scene) {
  const group = new THREE.Group();
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
    group.add(fan(wingCentre, wingLoop));
    group.add(tube(crest, 0.007));
    group.add(tube([acetabulum, get("pubic"), [0.0, flip(lm.pubic_symphysis)[1], flip(lm.pubic_symphysis)[2]]], 0.009));
    group.add(tube([get("pubic"), [get("pubic")[0] * 1.3, -0.03, -0.11], tuberosity], 0.007));
    group.add(tube([acetabulum, ischialSpine, tuberosity], 0.01));
    group.add(hemisphereCup(acetabulum, axis, scene.rim_radius_m));
    group.add(tube([get("psis"), [get("psis")[0] * 0.35, -0.16, 0.0], [0, -0.14, -0.06]], 0.012)); // sacrum edge
  }
  return group;
}

function markerArray(markers, radius = 0.0065) {
  const group = new THREE.Group();
  const materials = [];
  for (const m of markers) {
    const material = new THREE.MeshLambertMaterial({ color: GREEN, emissive: 0x000000 });
    const ball = new THREE.Mesh(new THREE.SphereGeometry(radius, 16, 12), material);
    ball.position.copy(v(m));
    group.add(ball);
    materials.push(material);
  }
  const plate = new THREE.Mesh(new THREE.BoxGeometry(0.07, 0.1, 0.004), new THREE.MeshLambertMaterial({ color: 0x505a66 }));
  plate.position.set(0, 0, -0.004);
  group.add(plate);
  return { group, materials };
}

function rod(from, to, radius, color) {
  const a = v(from), b = v(to);
  const length = a.distanceTo(b);
  const mesh = new THREE.Mesh(new THREE.CylinderGeometry(radius, radius, length, 10), new THREE.MeshLambertMaterial({ color }));
  mesh.position.copy(a.clone().add(b).multiplyScalar(0.5));
  mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), b.clone().sub(a).normalize());
  return mesh;
}

function buildTool(name, scene) {
  const { group, materials } = markerArray(scene.tool_markers[name]);
  group.matrixAutoUpdate = false;
  const tip = scene.tool_tips[name];
  const extras = { pose: new THREE.Matrix4() };
  if (name === "Probe") {
    group.add(rod([0, 0, 0], tip, 0.003, 0xb0b8c0));
  } else if (name === "Reamer") {
    group.add(rod([0, 0, 0], tip, 0.005, 0xb0b8c0));
    const radius = scene.reamer_head_diameter_m / 2;
    const head = new THREE.Mesh(
      new THREE.SphereGeometry(radius, 24, 12, 0, Math.PI * 2, 0, Math.PI / 2),
      new THREE.MeshLambertMaterial({ color: 0xc0c6cc, side: THREE.DoubleSide }),
    );
    head.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), new THREE.Vector3(0, 0, -1)); // dome into the bone (−z)
    head.position.copy(v(tip));
    group.add(head);
    // The ray: the reamer axis through the head centre, coloured by the safe zone.
    const ray = new THREE.Mesh(new THREE.CylinderGeometry(0.0025, 0.0025, 0.5, 8), new THREE.MeshBasicMaterial({ color: GREY }));
    ray.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), new THREE.Vector3(0, 0, 1));
    ray.position.set(tip[0], tip[1], tip[2] + 0.08);
    group.add(ray);
    extras.ray = ray;
  }
  return { group, materials, ...extras };
}

function buildCamera(volume) {
  // Camera frame: +z along the view, x right, y down; the volume is a truncated pyramid.
  const group = new THREE.Group();
  group.matrixAutoUpdate = false;
  const body = new THREE.Mesh(new THREE.BoxGeometry(0.5, 0.07, 0.08), new THREE.MeshLambertMaterial({ color: 0x30363d }));
  group.add(body);
  for (const x of [-0.22, 0.22]) {
    const lens = new THREE.Mesh(new THREE.CylinderGeometry(0.03, 0.03, 0.02, 20), new THREE.MeshLambertMaterial({ color: 0x7030a0, emissive: 0x300050 }));
    lens.rotation.x = Math.PI / 2;
    lens.position.set(x, 0, 0.045);
    group.add(lens);
  }
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
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio, 1.5));
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x1b2026);
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.01, 20);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x404040, 1.6));
    const sun = new THREE.DirectionalLight(0xffffff, 1.4);
    sun.position.set(1, 2, 1.5);
    this.scene.add(sun);
    this.root = new THREE.Group();
    this.scene.add(this.root);
    const grid = new THREE.GridHelper(4, 40, 0x3a434d, 0x2b323a); // the operating table's plane
    grid.position.y = -0.2;
    this.scene.add(grid);
    this.pickable = [];
    this.content = null;
  }

  resize(width, height) {
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
  }

  build(scene) {
    if (this.content) this.root.remove(this.content);
    this.content = new THREE.Group();
    this.root.add(this.content);
    this.sceneInfo = scene;
    this.content.add(buildPelvis(scene));
    this.landmarks = {};
    this.pickable = [];
    for (const [name, p] of Object.entries(scene.landmarks)) {
      const ball = new THREE.Mesh(new THREE.SphereGeometry(0.004, 14, 10), new THREE.MeshLambertMaterial({ color: GREY, emissive: 0x000000 }));
      ball.position.copy(v(p));
      ball.userData.landmark = name;
      this.content.add(ball);
      this.landmarks[name] = ball;
      // A larger invisible sphere makes the small point easy to click.
      const hit = new THREE.Mesh(new THREE.SphereGeometry(0.012, 8, 6), new THREE.MeshBasicMaterial({ visible: false }));
      hit.position.copy(v(p));
      hit.userData.landmark = name;
      this.content.add(hit);
      this.pickable.push(hit);
    }
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
    this.irCamera.matrix.copy(matrixFromRowMajor(state.camera.pose));
    for (const [name, tool] of Object.entries(this.tools)) {
      const info = state.tools[name];
      tool.group.visible = info.pose !== null;
      if (info.pose) {
        tool.pose.copy(matrixFromRowMajor(info.pose));
        tool.group.matrix.copy(tool.pose);
      }
      for (const m of tool.materials) m.color.setHex(info.tracked ? GREEN : RED);
    }
    const ray = this.tools.Reamer.ray;
    ray.material.color.setHex(state.zone ? ZONE_COLOURS[state.zone.colour] : GREY);
    this.occluder.visible = state.occluder.boxes.length > 0;
    if (this.occluder.visible) {
      const box = state.occluder.boxes[0];
      this.occluder.matrix.copy(matrixFromRowMajor(box.pose)).multiply(new THREE.Matrix4().makeScale(...box.size));
    }
    this.registration = state.registration;
  }

  // Per drawn frame: the landmark to touch next pulses; acquired ones are green.
  animate() {
    const reg = this.registration;
    if (!reg || !this.landmarks) return;
    const pulse = 1 + 0.5 * Math.abs(Math.sin(performance.now() / 200));
    for (const [name, ball] of Object.entries(this.landmarks)) {
      const acquired = reg.acquired.includes(name);
      const current = reg.current === name;
      ball.material.color.setHex(acquired ? GREEN : current ? YELLOW : GREY);
      ball.material.emissive.setHex(current ? 0x806000 : 0x000000);
      ball.scale.setScalar(current ? pulse * 1.6 : 1);
    }
  }

  // Turns the reamer about its own axis (tool z) from its last pose: a scene that changes every
  // frame, for measuring drawing speed (?continuous=1).
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

  pick(ndcX, ndcY) {
    const caster = new THREE.Raycaster();
    caster.setFromCamera(new THREE.Vector2(ndcX, ndcY), this.camera);
    const hit = caster.intersectObjects(this.pickable, false)[0];
    return hit ? hit.object.userData.landmark : null;
  }

  render() { this.renderer.render(this.scene, this.camera); }
}
