// The acetabular bone being reamed (the thesis's patch of the socket's floor, or the whole layered
// socket): the remaining bone's boundary faces. The mesh arrives once (GET /api/reaming/mesh:
// nodes in mm in the bone's frame, tets, face neighbours, and from version 2 each element's
// material with the materials' names); after that each element is one byte (0 removed, 1..levels
// α from the removal threshold to 1), kept up to date by the compressed keyframes and deltas the
// server streams (thrsim/app/bone_stream.py). A face is drawn when its tet remains and the tet
// across it does not (or there is none): the same boundary the offscreen renderer draws.
// Colours: by depth against the planned hemisphere (DEPTH_STOPS, computed per pixel from the
// plan's centre and radius, so a new plan recolours nothing on the CPU; native faces beyond the
// plan, NATIVE_COLOUR), or by the bone's layer (its elements' materials, LAYER_COLOURS).
import * as THREE from "three";

// Outward faces of a positively oriented tet, opposite vertex 0, 1, 2, 3 (thrsim.geometry.tet_metrics).
const FACES = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

// Depth of the cut surface against the planned hemisphere (mm: its distance from the plan's centre
// less the plan's radius), as the report's cavity map: bone short of the plan amber, within
// 0.45 mm (the mesh's resolution) green, beyond it red, darkening toward 2 mm beyond.
export const DEPTH_STOPS = [[-2, "#e3dccb"], [-1, "#f2c14e"], [-0.45, "#2ca25f"], [0.45, "#2ca25f"], [1, "#d7301f"], [2, "#5a0d0d"]];
// The bone's layers (thrsim.geometry.mesh's material names): cortical ivory, cancellous the red of
// bleeding cancellous bone; a name not listed is grey.
export const LAYER_COLOURS = { cortical: "#efe6cf", cancellous: "#c8645a" };
// Native bone (a face no reamer made) beyond the plan is no depth to show: the whole socket's rim,
// fossa and outer faces, drawn plain grey with depth colours on. Beyond this (mm) a native face is grey.
export const NATIVE_COLOUR = "#b9b9b9";
const NATIVE_BEYOND_MM = DEPTH_STOPS[3][0];
const OTHER_LAYER = "#9a9a9a";

// GLSL: the depth colour of a distance beyond the plan (mm), piecewise linear between the stops
// (the stops are sRGB; three.js shades in linear, as THREE.Color holds them).
function depthColourGlsl() {
  const rgb = (hex) => `vec3(${new THREE.Color(hex).toArray().map((x) => x.toFixed(4)).join(", ")})`;
  const lines = ["vec3 depthColour(float d) {", `  vec3 c = ${rgb(DEPTH_STOPS[0][1])};`];
  for (let i = 1; i < DEPTH_STOPS.length; i++) {
    const [x0, a] = DEPTH_STOPS[i - 1], [x1, b] = DEPTH_STOPS[i];
    lines.push(`  if (d > ${x0.toFixed(3)}) c = mix(${rgb(a)}, ${rgb(b)}, clamp((d - (${x0.toFixed(3)})) / ${(x1 - x0).toFixed(3)}, 0.0, 1.0));`);
  }
  lines.push("  return c;", "}");
  return lines.join("\n");
}

// The bone's material: vertex colours (the layers) or, with depth colours on, each pixel's depth
// against the plan. Its userData.plan holds the uniforms: the plan's centre and radius (mm, the
// bone's frame) and whether depth colours are on.
function boneMaterial() {
  const material = new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.FrontSide });
  const plan = { planCentre: { value: new THREE.Vector3() }, planRadius: { value: 0 }, depthColours: { value: 1 } };
  const native = `vec3(${new THREE.Color(NATIVE_COLOUR).toArray().map((x) => x.toFixed(4)).join(", ")})`;
  material.userData.plan = plan;
  material.onBeforeCompile = (shader) => {
    Object.assign(shader.uniforms, plan);
    shader.vertexShader = shader.vertexShader
      .replace("#include <common>", "#include <common>\nvarying vec3 vBonePoint;\nattribute float cutFace;\nvarying float vCut;")
      .replace("#include <begin_vertex>", "#include <begin_vertex>\nvBonePoint = transformed;\nvCut = cutFace;");
    shader.fragmentShader = shader.fragmentShader
      .replace("#include <common>", `#include <common>\nvarying vec3 vBonePoint;\nvarying float vCut;\nuniform vec3 planCentre;\nuniform float planRadius;\nuniform float depthColours;\n${depthColourGlsl()}`)
      .replace("#include <color_fragment>", `#include <color_fragment>
if (depthColours > 0.5) {
  float d = length(vBonePoint - planCentre) - planRadius;
  diffuseColor.rgb = vCut > 0.5 || d <= ${NATIVE_BEYOND_MM.toFixed(3)} ? depthColour(d) : ${native};
}`);
  };
  return material;
}

async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

export function parseMesh(buffer) {
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== "THRM") throw new Error(`not a thrsim reaming mesh (${magic})`);
  const version = view.getUint32(4, true), nodes = view.getUint32(8, true), tets = view.getUint32(12, true);
  let offset = 16;
  const positions = new Float32Array(buffer.slice(offset, offset + nodes * 12)); offset += nodes * 12;
  const indices = new Uint32Array(buffer.slice(offset, offset + tets * 16)); offset += tets * 16;
  const neighbours = new Int32Array(buffer.slice(offset, offset + tets * 16)); offset += tets * 16;
  let materials = new Uint8Array(tets), materialNames = ["cortical"]; // version 1: one material
  if (version >= 2) {
    materials = new Uint8Array(buffer.slice(offset, offset + tets)); offset += tets;
    const length = view.getUint32(offset, true); offset += 4;
    materialNames = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, offset, length)));
  }
  return { nodes, tets, positions, indices, neighbours, materials, materialNames };
}

// A face's slot in the vertex buffers is kept while the face stays on the boundary, so a frame
// rewrites and re-uploads only the slots of faces it changed (a few hundred of ~5,500 while
// reaming) instead of visiting all 80,000 tet faces and uploading ~600 kB. A freed slot is written degenerate (zero area: never rasterised) and
// reused by the next new face; the draw range is the highest slot ever used since the last
// rebuild (free slots inside it stay on the free list, so it does not grow with the session).
const MERGE_GAP_SLOTS = 32; // changed slots closer than this are uploaded as one range

export class BonePatch {
  constructor(mesh, placementRowMajor) {
    this.mesh = mesh;
    this.levels = new Uint8Array(mesh.tets);
    this.colours = mesh.materialNames.map((name) => new THREE.Color(LAYER_COLOURS[name] ?? OTHER_LAYER).toArray());
    this.frame = -1;
    this.visibleFaces = 0;
    const capacity = mesh.tets * 4; // faces
    this.slotOf = new Int32Array(capacity).fill(-1); // face (4·tet + f) → slot, −1 when not drawn
    this.faceAt = new Int32Array(capacity).fill(-1); // slot → face, −1 when free
    this.freeSlots = [];
    this.slotsUsed = 0; // slots below this are drawn (free ones degenerate)
    this.changedSlots = [];
    this.positions = new Float32Array(capacity * 9);
    this.normals = new Float32Array(capacity * 9);
    this.rgb = new Float32Array(capacity * 9);
    this.cut = new Float32Array(capacity * 3); // 1 on a face a reamer made (the tet across it removed), 0 on a native face
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(this.positions, 3).setUsage(THREE.DynamicDrawUsage));
    geometry.setAttribute("normal", new THREE.BufferAttribute(this.normals, 3).setUsage(THREE.DynamicDrawUsage));
    geometry.setAttribute("color", new THREE.BufferAttribute(this.rgb, 3).setUsage(THREE.DynamicDrawUsage));
    geometry.setAttribute("cutFace", new THREE.BufferAttribute(this.cut, 1).setUsage(THREE.DynamicDrawUsage));
    geometry.setDrawRange(0, 0);
    // Front faces only: the faces are the remaining bone's outward boundary, so a back face is
    // always behind a front one (culling halves SwiftShader's shading of the patch).
    this.object = new THREE.Mesh(geometry, boneMaterial());
    this.object.matrixAutoUpdate = false;
    // patch frame (mm) → pelvis model frame (m): the server's placement, mirrored for a left hip
    this.object.matrix.set(...placementRowMajor).multiply(new THREE.Matrix4().makeScale(1e-3, 1e-3, 1e-3));
    this.object.frustumCulled = false;
  }

  // Apply binary frames (keyframes or deltas, each body a zlib stream) in the order they arrived,
  // all at once: their bodies inflate together and the faces are refreshed once for the lot, so a
  // backlog (frames that came while the page drew) costs one refresh, not one per frame; resolves
  // to the last frame number. The caller chains calls, so frames never apply out of order.
  async apply(...buffers) {
    const frames = await Promise.all(buffers.map(async (buffer) => {
      const view = new DataView(buffer);
      const kind = String.fromCharCode(view.getUint8(0));
      return { kind, frame: view.getUint32(1, true), count: view.getUint32(5, true), body: await inflate(new Uint8Array(buffer, 9)) };
    }));
    let rebuild = false;
    const changed = [];
    for (const { kind, frame, count, body } of frames) {
      if (kind === "K") {
        if (count !== this.levels.length || body.length !== count) throw new Error(`keyframe of ${count} elements for a mesh of ${this.levels.length}`);
        this.levels.set(body);
        rebuild = true;
      } else if (kind === "D") {
        // ids ascending, each the gap to the previous one minus one as a LEB128 varint; then the levels
        let read = 0, id = -1;
        const ids = new Uint32Array(count);
        for (let i = 0; i < count; i++) {
          let gap = 0, shift = 0, byte;
          do { byte = body[read++]; gap += (byte & 0x7f) * 2 ** shift; shift += 7; } while (byte & 0x80);
          id += gap + 1;
          ids[i] = id;
        }
        if (read + count !== body.length || (count && id >= this.levels.length)) throw new Error(`malformed delta of ${count} elements`);
        for (let i = 0; i < count; i++) this.levels[ids[i]] = body[read + i];
        changed.push(ids);
      } else {
        throw new Error(`unknown bone frame ${kind}`);
      }
      this.frame = frame;
    }
    if (rebuild) this.rebuild();
    else if (changed.length) this.update(changed.length === 1 ? changed[0] : new Uint32Array(new Set(changed.flatMap((ids) => [...ids]))));
    return this.frame;
  }

  // Every boundary face of the remaining bone from scratch (a keyframe, a new patch), in order.
  rebuild() {
    this.slotOf.fill(-1);
    this.faceAt.fill(-1);
    this.freeSlots = [];
    this.slotsUsed = 0;
    this.visibleFaces = 0;
    for (let face = 0; face < this.slotOf.length; face++) if (this.drawn(face)) this.place(face);
    this.upload([[0, this.slotsUsed]]);
  }

  // The faces of the changed tets and the faces of their neighbours across them: all that a
  // change of these tets' levels can show, hide or recolour.
  update(ids) {
    const { neighbours } = this.mesh;
    this.changedSlots.length = 0;
    for (const tet of ids) {
      for (let f = 0; f < 4; f++) {
        this.refresh(4 * tet + f);
        const across = neighbours[4 * tet + f];
        if (across < 0) continue;
        for (let g = 0; g < 4; g++) if (neighbours[4 * across + g] === tet) this.refresh(4 * across + g);
      }
    }
    const slots = this.changedSlots.sort((a, b) => a - b);
    const ranges = [];
    for (const slot of slots) {
      const last = ranges[ranges.length - 1];
      if (last && slot - last[1] <= MERGE_GAP_SLOTS) last[1] = slot + 1;
      else ranges.push([slot, slot + 1]);
    }
    this.upload(ranges);
  }

  drawn(face) {
    const tet = face >> 2, levels = this.levels;
    if (levels[tet] === 0) return false;
    const across = this.mesh.neighbours[face];
    return across < 0 || levels[across] === 0;
  }

  refresh(face) {
    const slot = this.slotOf[face];
    if (this.drawn(face)) {
      if (slot < 0) this.place(face);
      else this.write(slot, face); // its tet's level may have changed: its colour did
      this.changedSlots.push(this.slotOf[face]);
    } else if (slot >= 0) {
      this.positions.fill(0, 9 * slot, 9 * slot + 9); // degenerate: nothing rasterised
      this.slotOf[face] = -1;
      this.faceAt[slot] = -1;
      this.freeSlots.push(slot);
      this.visibleFaces -= 1;
      this.changedSlots.push(slot);
    }
  }

  place(face) {
    const slot = this.freeSlots.length ? this.freeSlots.pop() : this.slotsUsed++;
    this.slotOf[face] = slot;
    this.faceAt[slot] = face;
    this.visibleFaces += 1;
    this.write(slot, face);
  }

  // The planned hemisphere (centre in mm in the bone's frame, radius in mm) the depth colours measure against.
  setPlan(centreMm, radiusMm) {
    const plan = this.object.material.userData.plan;
    plan.planCentre.value.fromArray(centreMm);
    plan.planRadius.value = radiusMm;
  }

  // Colour by depth against the plan (true) or by the bone's layers (false).
  setDepthColours(on) { this.object.material.userData.plan.depthColours.value = on ? 1 : 0; }

  // One face's three vertices: positions, its flat outward normal, its tet's layer colour.
  write(slot, face) {
    const { positions: nodes, indices } = this.mesh;
    const tet = face >> 2, corners = FACES[face & 3], colour = this.colours[this.mesh.materials[tet]];
    const a = 3 * indices[4 * tet + corners[0]], b = 3 * indices[4 * tet + corners[1]], c = 3 * indices[4 * tet + corners[2]];
    const ux = nodes[b] - nodes[a], uy = nodes[b + 1] - nodes[a + 1], uz = nodes[b + 2] - nodes[a + 2];
    const vx = nodes[c] - nodes[a], vy = nodes[c + 1] - nodes[a + 1], vz = nodes[c + 2] - nodes[a + 2];
    let nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    const length = Math.hypot(nx, ny, nz) || 1;
    nx /= length; ny /= length; nz /= length;
    const pos = this.positions, nor = this.normals, rgb = this.rgb;
    this.cut.fill(this.mesh.neighbours[face] >= 0 ? 1 : 0, 3 * slot, 3 * slot + 3);
    let w = 9 * slot;
    for (const node of [a, b, c]) {
      pos[w] = nodes[node]; pos[w + 1] = nodes[node + 1]; pos[w + 2] = nodes[node + 2];
      nor[w] = nx; nor[w + 1] = ny; nor[w + 2] = nz;
      rgb[w] = colour[0]; rgb[w + 1] = colour[1]; rgb[w + 2] = colour[2];
      w += 3;
    }
  }

  // Ranges of slots [first, end) whose vertices go to the GPU with the next drawing (three.js
  // keeps adding ranges until it uploads them, so frames applied between two drawings all go).
  upload(ranges) {
    const geometry = this.object.geometry;
    geometry.setDrawRange(0, 3 * this.slotsUsed);
    if (!ranges.length) return;
    for (const name of ["position", "normal", "color", "cutFace"]) {
      const attribute = geometry.attributes[name], per = 3 * attribute.itemSize; // values a face slot holds
      for (const [first, end] of ranges) attribute.addUpdateRange(per * first, per * (end - first));
      attribute.needsUpdate = true;
    }
  }

  // Occupied slots as sorted "face:9 positions:3 colour" strings, to compare with a rebuild.
  faceSignature() {
    const rows = [];
    for (let slot = 0; slot < this.slotsUsed; slot++) {
      const face = this.faceAt[slot];
      if (face < 0) continue;
      rows.push(`${face}:${Array.from(this.positions.subarray(9 * slot, 9 * slot + 9)).join(",")}:${Array.from(this.rgb.subarray(9 * slot, 9 * slot + 3)).join(",")}`);
    }
    return rows.sort().join(";");
  }

  removedCount() {
    let n = 0;
    for (const level of this.levels) if (level === 0) n++;
    return n;
  }
}
