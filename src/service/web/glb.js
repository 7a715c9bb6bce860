// A minimal reader of binary glTF (GLB) as written by the service: the
// triangle primitives of every mesh, their POSITION, the optional
// per-vertex results (_LABEL, _MEAN_CURVATURE, _GAUSSIAN_CURVATURE,
// _DISPLACEMENT) and the indices, concatenated into typed arrays. Node
// transforms are not applied: the service writes positions in the file's
// own frame, and before and after share it.

const COMPONENTS = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 };
const ARRAYS = {
  5120: Int8Array, 5121: Uint8Array, 5122: Int16Array,
  5123: Uint16Array, 5125: Uint32Array, 5126: Float32Array,
};
const TRIANGLES = 4;
const RESULTS = ['_LABEL', '_MEAN_CURVATURE', '_GAUSSIAN_CURVATURE', '_DISPLACEMENT'];

/** Reads accessor `index` of `json` over the binary chunk `bin` into a
 * Float32Array (or Uint32Array for indices). */
function readAccessor(json, bin, index, asIndices) {
  const acc = json.accessors?.[index];
  if (!acc) throw new Error(`accessor ${index} missing`);
  const width = COMPONENTS[acc.type];
  const Src = ARRAYS[acc.componentType];
  if (!width || !Src) throw new Error(`accessor ${index}: unsupported type`);
  const out = new (asIndices ? Uint32Array : Float32Array)(acc.count * width);
  if (acc.bufferView === undefined) return out; // all zeros (glTF 3.6.2.1)
  const view = json.bufferViews?.[acc.bufferView];
  if (!view || (view.buffer ?? 0) !== 0) throw new Error(`accessor ${index}: buffer not in the GLB`);
  const size = Src.BYTES_PER_ELEMENT;
  const stride = view.byteStride || width * size;
  const start = bin.byteOffset + (view.byteOffset ?? 0) + (acc.byteOffset ?? 0);
  if (start + stride * (acc.count - 1) + width * size > bin.byteOffset + bin.byteLength) {
    throw new Error(`accessor ${index} runs past the binary chunk`);
  }
  if (stride === width * size && start % size === 0) {
    out.set(new Src(bin.buffer, start, acc.count * width));
    return out;
  }
  const data = new DataView(bin.buffer);
  const getter = {
    5120: 'getInt8', 5121: 'getUint8', 5122: 'getInt16',
    5123: 'getUint16', 5125: 'getUint32', 5126: 'getFloat32',
  }[acc.componentType];
  for (let i = 0; i < acc.count; i++) {
    for (let c = 0; c < width; c++) {
      out[i * width + c] = data[getter](start + i * stride + c * size, true);
    }
  }
  return out;
}

/** Parses a GLB: { positions, indices, results: {name: Float32Array} }. */
export function parseGlb(buffer) {
  const head = new DataView(buffer);
  if (buffer.byteLength < 20 || head.getUint32(0, true) !== 0x46546c67) {
    throw new Error('not a GLB file');
  }
  let offset = 12;
  let json = null;
  let bin = null;
  while (offset + 8 <= buffer.byteLength) {
    const length = head.getUint32(offset, true);
    const type = head.getUint32(offset + 4, true);
    const body = new Uint8Array(buffer, offset + 8, Math.min(length, buffer.byteLength - offset - 8));
    if (type === 0x4e4f534a) json = JSON.parse(new TextDecoder().decode(body));
    else if (type === 0x004e4942) bin = body;
    offset += 8 + length;
  }
  if (!json || !bin) throw new Error('GLB without a JSON or binary chunk');
  const parts = [];
  for (const mesh of json.meshes ?? []) {
    for (const prim of mesh.primitives ?? []) {
      if ((prim.mode ?? TRIANGLES) !== TRIANGLES || prim.attributes?.POSITION === undefined) continue;
      const positions = readAccessor(json, bin, prim.attributes.POSITION, false);
      const n = positions.length / 3;
      const indices = prim.indices === undefined
        ? Uint32Array.from({ length: n }, (_, i) => i)
        : readAccessor(json, bin, prim.indices, true);
      const results = {};
      for (const name of RESULTS) {
        if (prim.attributes[name] !== undefined) results[name] = readAccessor(json, bin, prim.attributes[name], false);
      }
      parts.push({ positions, indices, results });
    }
  }
  if (parts.length === 0) throw new Error('GLB without triangles');
  return concat(parts);
}

function concat(parts) {
  if (parts.length === 1) return parts[0];
  const nv = parts.reduce((s, p) => s + p.positions.length, 0);
  const ni = parts.reduce((s, p) => s + p.indices.length, 0);
  const positions = new Float32Array(nv);
  const indices = new Uint32Array(ni);
  const names = RESULTS.filter((r) => parts.every((p) => p.results[r]));
  const results = Object.fromEntries(names.map((r) => [r, new Float32Array(nv / 3)]));
  let v = 0;
  let i = 0;
  for (const p of parts) {
    positions.set(p.positions, v * 3);
    for (let k = 0; k < p.indices.length; k++) indices[i + k] = p.indices[k] + v;
    for (const r of names) results[r].set(p.results[r], v);
    v += p.positions.length / 3;
    i += p.indices.length;
  }
  return { positions, indices, results };
}
