// The acetabular bone patch being reamed: the remaining bone's boundary faces, coloured by α.
// The mesh arrives once (GET /api/reaming/mesh: nodes in mm in the patch frame, tets, face
// neighbours); after that each element is one byte (0 removed, 1..levels α from the removal
// threshold to 1), kept up to date by the compressed keyframes and deltas the server streams
// (thrsim/app/bone_stream.py). A face is drawn when its tet remains and the tet across it does
// not (or there is none): the same boundary the offscreen renderer draws.
import * as THREE from "three";

// Outward faces of a positively oriented tet, opposite vertex 0, 1, 2, 3 (thrsim.geometry.tet_metrics).
const FACES = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

// viridis at 8 stops, from the removal threshold (dark) to α = 1 (light), as the offscreen renderer.
const VIRIDIS = [[0.267, 0.005, 0.329], [0.275, 0.194, 0.497], [0.213, 0.359, 0.552], [0.153, 0.498, 0.558],
  [0.122, 0.632, 0.531], [0.29, 0.758, 0.428], [0.626, 0.854, 0.223], [0.993, 0.906, 0.144]];

function palette(levels) {
  const colours = [[0, 0, 0]];
  for (let k = 1; k <= levels; k++) {
    const x = ((k - 0.5) / levels) * (VIRIDIS.length - 1);
    const i = Math.min(VIRIDIS.length - 2, Math.floor(x)), t = x - i;
    colours.push(VIRIDIS[i].map((c, j) => c + t * (VIRIDIS[i + 1][j] - c)));
  }
  return colours;
}

async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

export function parseMesh(buffer) {
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== "THRM") throw new Error(`not a thrsim reaming mesh (${magic})`);
  const nodes = view.getUint32(8, true), tets = view.getUint32(12, true);
  let offset = 16;
  const positions = new Float32Array(buffer.slice(offset, offset + nodes * 12)); offset += nodes * 12;
  const indices = new Uint32Array(buffer.slice(offset, offset + tets * 16)); offset += tets * 16;
  const neighbours = new Int32Array(buffer.slice(offset, offset + tets * 16));
  return { nodes, tets, positions, indices, neighbours };
}

// A face's slot in the vertex buffers is kept while the face stays on the boundary, so a frame
// rewrites and re-uploads only the slots of faces it changed (a few hundred of ~5,500 while
// reaming) instead of visiting all 80,000 tet faces and uploading ~600 kB. A freed slot is written degenerate (zero area: never rasterised) and
// reused by the next new face; the draw range is the highest slot ever used since the last
// rebuild (free slots inside it stay on the free list, so it does not grow with the session).
const MERGE_GAP_SLOTS = 32; // changed slots closer than this are uploaded as one range

export class BonePatch {
  constructor(mesh, placementRowMajor, levels) {
    this.mesh = mesh;
    this.levels = new Uint8Array(mesh.tets);
    this.colours = palette(levels);
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
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(this.positions, 3).setUsage(THREE.DynamicDrawUsage));
    geometry.setAttribute("normal", new THREE.BufferAttribute(this.normals, 3).setUsage(THREE.DynamicDrawUsage));
    geometry.setAttribute("color", new THREE.BufferAttribute(this.rgb, 3).setUsage(THREE.DynamicDrawUsage));
    geometry.setDrawRange(0, 0);
    // Front faces only: the faces are the remaining bone's outward boundary, so a back face is
    // always behind a front one (culling halves SwiftShader's shading of the patch).
    this.object = new THREE.Mesh(geometry, new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.FrontSide }));
    this.object.matrixAutoUpdate = false;
    // patch frame (mm) → pelvis model frame (m): the server's placement, mirrored for a left hip
    this.object.matrix.set(...placementRowMajor).multiply(new THREE.Matrix4().makeScale(1e-3, 1e-3, 1e-3));
    this.object.frustumCulled = false;
  }

  // Apply one binary frame (keyframe or delta, its body a zlib stream); resolves to the frame
  // number. Frames must be applied in the order they arrived (the caller chains them).
  async apply(buffer) {
    const view = new DataView(buffer);
    const kind = String.fromCharCode(view.getUint8(0));
    const frame = view.getUint32(1, true), count = view.getUint32(5, true);
    const body = await inflate(new Uint8Array(buffer, 9));
    if (kind === "K") {
      if (count !== this.levels.length || body.length !== count) throw new Error(`keyframe of ${count} elements for a mesh of ${this.levels.length}`);
      this.levels.set(body);
      this.frame = frame;
      this.rebuild();
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
      this.frame = frame;
      this.update(ids);
    } else {
      throw new Error(`unknown bone frame ${kind}`);
    }
    return frame;
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

  // One face's three vertices: positions, its flat outward normal, its tet's colour.
  write(slot, face) {
    const { positions: nodes, indices } = this.mesh;
    const tet = face >> 2, corners = FACES[face & 3], colour = this.colours[this.levels[tet]];
    const a = 3 * indices[4 * tet + corners[0]], b = 3 * indices[4 * tet + corners[1]], c = 3 * indices[4 * tet + corners[2]];
    const ux = nodes[b] - nodes[a], uy = nodes[b + 1] - nodes[a + 1], uz = nodes[b + 2] - nodes[a + 2];
    const vx = nodes[c] - nodes[a], vy = nodes[c + 1] - nodes[a + 1], vz = nodes[c + 2] - nodes[a + 2];
    let nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    const length = Math.hypot(nx, ny, nz) || 1;
    nx /= length; ny /= length; nz /= length;
    const pos = this.positions, nor = this.normals, rgb = this.rgb;
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
    for (const name of ["position", "normal", "color"]) {
      const attribute = geometry.attributes[name];
      for (const [first, end] of ranges) attribute.addUpdateRange(9 * first, 9 * (end - first));
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
