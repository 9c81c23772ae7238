// A second 3D Tiles client: loaders.gl (@loaders.gl/3d-tiles, core, gltf, textures) in Node, offline.
//
//   node tests/js/loadersgl_parse.mjs tileset <tileset.json>    parse the tileset (explicit children, and
//        implicitTiling expanded by loaders.gl's own subtree loader), then every content with Tiles3DLoader
//        (GLTFLoader inside it: EXT_meshopt_compression, KHR_texture_basisu, EXT_texture_webp decoded); prints
//        {tiles, subtrees, contents: [per-content report], fetched, network}
//   node tests/js/loadersgl_parse.mjs texture <file.ktx2>       BasisLoader alone: every mip level to RGBA8
//   node tests/js/loadersgl_parse.mjs fixture-glb <out.glb> <image.ktx2>   write a small glb the way the compact
//        stream does (KHR_mesh_quantization, EXT_meshopt_compression by meshoptimizer's MeshoptEncoder,
//        KHR_texture_basisu, EXT_mesh_features + EXT_structural_metadata); prints what it holds
//
// Offline: the Basis transcoder comes from node_modules/@loaders.gl/textures/dist/libs (loaders.gl would
// otherwise build a CDN or a relative `modules/...` URL for it), meshopt's wasm is embedded in meshoptimizer,
// workers are off, and WebP goes to sharp through loaders.gl's Node image hook. Every network attempt (fetch,
// a socket) is recorded and fails the run (exit 2).
import fs from 'node:fs';
import net from 'node:net';
import path from 'node:path';
import vm from 'node:vm';
import {createRequire} from 'node:module';
import {fileURLToPath} from 'node:url';

const require = createRequire(import.meta.url);
const network = [];

// --- no network: recorded, then refused ---------------------------------------------------------------------
globalThis.fetch = async (url) => {
  network.push(String(url?.url ?? url));
  throw new Error(`network fetch refused (offline client): ${url}`);
};
const connect = net.Socket.prototype.connect;
net.Socket.prototype.connect = function (...args) {
  const o = args[0];
  // a socket to a host or port is the network; a Unix-domain path (o.path) is local IPC
  if (!(o && typeof o === 'object' && o.path)) {
    network.push(`socket ${JSON.stringify(typeof o === 'object' ? {host: o.host, port: o.port} : args.slice(0, 2))}`);
    throw new Error('network socket refused (offline client)');
  }
  return connect.apply(this, args);
};

// WebP/PNG/JPEG in Node: loaders.gl's ImageLoader hands image bytes to globalThis.loaders.parseImageNode (what
// @loaders.gl/polyfills installs); sharp (node_modules) decodes them. Set before loaders.gl is
// imported: @loaders.gl/images reads the hook at import time.
const sharp = (await import('sharp')).default;
globalThis.loaders = globalThis.loaders || {};
globalThis.loaders.imageFormatsNode = ['image/png', 'image/jpeg', 'image/webp'];
globalThis.loaders.parseImageNode = async (arrayBuffer) => {
  const {data, info} = await sharp(Buffer.from(arrayBuffer)).ensureAlpha().raw().toBuffer({resolveWithObject: true});
  return {shape: [info.width, info.height, 4], data: new Uint8Array(data), width: info.width, height: info.height,
    components: 4, layers: [1]};
};

const {load, parse} = await import('@loaders.gl/core');
const {Tiles3DLoader} = await import('@loaders.gl/3d-tiles');
const {BasisLoader} = await import('@loaders.gl/textures');

// --- decoders from node_modules -----------------------------------------------------------------------------
/** A package's directory (their exports maps hide package.json; the main entry is in <pkg>/dist/). */
const packageDir = (name) => path.dirname(path.dirname(require.resolve(name)));
const TEXTURES = packageDir('@loaders.gl/textures');
const LIBS = path.join(TEXTURES, 'dist', 'libs');

/** Evaluate an Emscripten UMD file as CommonJS (a plain require would load it as ESM: the package is "type":
 * "module", and the factory would be lost). */
function commonjs(file) {
  const m = {exports: {}};
  vm.compileFunction(fs.readFileSync(file, 'utf8'), ['module', 'exports', 'require', '__filename', '__dirname'],
    {filename: file})(m, m.exports, require, file, path.dirname(file));
  return m.exports;
}

/** The Basis module initialised from its local wasm. loaders.gl's `modules` option takes it ready-made
 * (basisEncoder: its KTX2 path, basis: its .basis path); handing it the wasm bytes instead does not work, its
 * option merging turns a typed array into a plain object. */
async function basisModule(name) {
  const factory = commonjs(path.join(LIBS, `${name}.js`));
  const m = await factory({wasmBinary: fs.readFileSync(path.join(LIBS, `${name}.wasm`))});
  m.initializeBasis();
  return {BasisFile: m.BasisFile, KTX2File: m.KTX2File};
}

const fetched = [];
/** loaders.gl's fetch: local files only (a URL is the network: refused). */
async function fileFetch(url) {
  const u = String(url);
  if (/^[a-z][a-z0-9+.-]*:/i.test(u) && !u.startsWith('file:')) {
    network.push(u);
    throw new Error(`network fetch refused (offline client): ${u}`);
  }
  const file = u.startsWith('file:') ? fileURLToPath(u) : u;
  fetched.push(file);
  const body = fs.readFileSync(file);
  const response = new Response(body, {status: 200, headers: {'content-type': 'application/octet-stream'}});
  // loaders.gl takes the base path for relative URIs (tileset contents, subtrees) from the response's url
  Object.defineProperty(response, 'url', {value: file});
  return response;
}

async function options() {
  return {
    core: {worker: false, fetch: fileFetch, CDN: null, useLocalLibraries: true},
    // LOADERSGL_DEFAULT_DECODERS=1 leaves them out: loaders.gl then fetches its own (the test of the guard)
    modules: process.env.LOADERSGL_DEFAULT_DECODERS === '1' ? {}
      : {basisEncoder: await basisModule('basis_encoder'), basis: await basisModule('basis_transcoder')},
    // any target is a real transcode; RGBA8 is the one Node can look at (a GPU client picks ASTC/BC7/ETC)
    basis: {format: 'rgba32'},
    gltf: {loadBuffers: true, loadImages: true, decompressMeshes: true},
    '3d-tiles': {loadGLTF: true, isTileset: 'auto'},
  };
}

// --- reports ------------------------------------------------------------------------------------------------
const NORM = {5120: 127, 5121: 255, 5122: 32767, 5123: 65535};

function mat4Mul(a, b) {  // column-major 4x4
  const o = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) for (let k = 0; k < 4; k++) o[c * 4 + r] += a[k * 4 + r] * b[c * 4 + k];
  return o;
}

function nodeMatrix(node) {
  if (node.matrix) return Array.from(node.matrix);
  const [tx, ty, tz] = node.translation || [0, 0, 0];
  const [x, y, z, w] = node.rotation || [0, 0, 0, 1];
  const [sx, sy, sz] = node.scale || [1, 1, 1];
  return [
    (1 - 2 * (y * y + z * z)) * sx, 2 * (x * y + z * w) * sx, 2 * (x * z - y * w) * sx, 0,
    2 * (x * y - z * w) * sy, (1 - 2 * (x * x + z * z)) * sy, 2 * (y * z + x * w) * sy, 0,
    2 * (x * z + y * w) * sz, 2 * (y * z - x * w) * sz, (1 - 2 * (x * x + y * y)) * sz, 0,
    tx, ty, tz, 1,
  ];
}

function jsonValue(v) {
  if (typeof v === 'bigint') return Number.isSafeInteger(Number(v)) ? Number(v) : v.toString();
  if (typeof v === 'number' && !Number.isFinite(v)) return String(v);
  return v;
}

function imageReport(img) {
  const im = img?.image ?? img;
  if (!im) return {decoded: false};
  if (im.compressed) {
    const levels = Array.isArray(im.data) ? im.data : [];
    return {decoded: levels.length > 0 && levels.every((l) => l.data?.length > 0), compressed: true,
      levels: levels.length, width: levels[0]?.width, height: levels[0]?.height,
      format: levels[0]?.textureFormat, levelSizes: levels.map((l) => [l.width, l.height])};
  }
  return {decoded: im.width > 0 && im.height > 0 && im.data?.length >= im.width * im.height * 3, compressed: false,
    levels: 1, width: im.width, height: im.height};
}

/** What a client needs of one content: geometry in the node frame, feature ids, the property table, images. */
function contentReport(gltf) {
  const out = {primitives: 0, vertices: 0, triangles: 0, positionsFinite: true, bbox: null, featureIdMax: -1,
    featureIdPresent: true, featureCounts: [], images: [], table: null};
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  const visit = (node, parent) => {
    const world = mat4Mul(parent, nodeMatrix(node));
    for (const prim of node.mesh?.primitives || []) {
      out.primitives += 1;
      const pos = prim.attributes.POSITION;
      const n = pos.count;
      out.vertices += n;
      out.triangles += prim.indices ? prim.indices.count / 3 : n / 3;
      const scale = pos.normalized ? 1 / NORM[pos.componentType] : 1;
      const v = pos.value;
      const stride = pos.components;
      for (let i = 0; i < n; i++) {
        const p = [v[i * stride] * scale, v[i * stride + 1] * scale, v[i * stride + 2] * scale];
        for (let r = 0; r < 3; r++) {
          const w = world[r] * p[0] + world[4 + r] * p[1] + world[8 + r] * p[2] + world[12 + r];
          if (!Number.isFinite(w)) out.positionsFinite = false;
          if (w < lo[r]) lo[r] = w;
          if (w > hi[r]) hi[r] = w;
        }
      }
      if (prim.indices) {
        const idx = prim.indices.value;
        for (let i = 0; i < idx.length; i++) if (idx[i] >= n) out.positionsFinite = false;  // an index past the end
      }
      // feature ids from the decoded attribute: loaders.gl's EXT_mesh_features runs before its meshopt decoder,
      // so its featureIds[].data would be read from still-compressed views
      const fid = prim.attributes._FEATURE_ID_0;
      const fx = prim.extensions?.EXT_mesh_features?.featureIds?.[0];
      if (!fid || !fx) {
        out.featureIdPresent = false;
      } else {
        let m = -1;
        for (let i = 0; i < fid.value.length; i++) if (fid.value[i] > m) m = fid.value[i];
        out.featureIdMax = Math.max(out.featureIdMax, m);
        out.featureCounts.push(fx.featureCount);
      }
    }
    for (const child of node.children || []) visit(child, world);
  };
  const scene = gltf.scene ?? gltf.scenes?.[0];
  const identity = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
  for (const node of scene?.nodes || []) visit(node, identity);
  out.bbox = out.vertices ? [lo, hi] : null;
  out.images = (gltf.images || []).map((im) => ({mimeType: im.mimeType, ...imageReport(im)}));
  const meta = gltf.extensions?.EXT_structural_metadata;
  const table = meta?.propertyTables?.[0];
  if (table) {
    const columns = {};
    const values = {};
    for (const [name, prop] of Object.entries(table.properties || {})) {
      const data = prop.data;
      columns[name] = data ? data.length : -1;
      if (name === 'osm_id' || name === 'height') values[name] = Array.from(data || [], jsonValue);
    }
    out.table = {class: table.class, count: table.count, columns, values};
  }
  return out;
}

/** Every tile of loaders.gl's normalised tree (implicit tiling already expanded into children). */
function* tilesOf(root) {
  const stack = [[root, 0]];
  while (stack.length) {
    const [tile, depth] = stack.pop();
    yield [tile, depth];
    for (const c of tile.children || []) stack.push([c, depth + 1]);
  }
}

async function cmdTileset(file) {
  const opts = await options();
  const t0 = Date.now();
  const tilesetPath = path.resolve(file);
  const base = path.dirname(tilesetPath);
  const tileset = await load(tilesetPath, Tiles3DLoader, {...opts, '3d-tiles': {...opts['3d-tiles'], isTileset: true}});
  const raw = JSON.parse(fs.readFileSync(tilesetPath, 'utf8'));
  const report = {asset: raw.asset, implicit: JSON.stringify(raw).includes('"implicitTiling"'), tiles: 0,
    contents: [],
    subtrees: [], errors: []};
  for (const [tile, depth] of tilesOf(tileset.root)) {
    report.tiles += 1;
    if (!tile.contentUrl) continue;
    const uri = path.relative(base, tile.contentUrl);
    const entry = {uri, depth, geometricError: tile.geometricError ?? tile.lodMetricValue,
      region: tile.boundingVolume?.region ?? null};
    try {
      const content = await load(tile.contentUrl, Tiles3DLoader, {...opts, '3d-tiles': {...opts['3d-tiles'],
        isTileset: false}});
      Object.assign(entry, {type: content.type, ...contentReport(content.gltf)});
    } catch (e) {
      entry.error = String(e?.stack || e);
      report.errors.push(`${uri}: ${e?.message || e}`);
    }
    report.contents.push(entry);
  }
  report.subtrees = [...new Set(fetched.filter((f) => f.endsWith('.subtree')).map((f) => path.relative(base, f)))]
    .sort();
  report.fetched = fetched.length;
  report.ms = Date.now() - t0;
  return report;
}

async function cmdTexture(file) {
  const opts = await options();
  const data = fs.readFileSync(file);
  const ab = data.buffer.slice(data.byteOffset, data.byteOffset + data.byteLength);
  const images = await parse(ab, BasisLoader, opts);
  const levels = images[0];
  return {images: images.length, levels: levels.map((l) => ({width: l.width, height: l.height,
    format: l.textureFormat, bytes: l.data.length})),
    level0: Buffer.from(levels[0].data.buffer, levels[0].data.byteOffset, levels[0].data.byteLength).toString('base64')};
}

// --- a hand-made compact glb ----------------------------------------------------------------------------------
async function cmdFixtureGlb(out, ktx2) {
  const {MeshoptEncoder} = await import(pathToMeshopt());
  await MeshoptEncoder.ready;
  // two boxes (features 0 and 1), positions quantized to int16 in a 1 cm grid, the node's matrix scales back
  const boxes = [[0, 0, 0, 10, 12, 8], [15, 0, 2, 22, 30, 9]];
  const pos = [];
  const fid = [];
  const uv = [];
  const idx = [];
  boxes.forEach(([x0, y0, z0, x1, y1, z1], f) => {
    const base = pos.length;
    for (let i = 0; i < 8; i++) {
      pos.push([(i & 1 ? x1 : x0), (i & 2 ? y1 : y0), (i & 4 ? z1 : z0)]);
      fid.push(f);
      uv.push([(i & 1), (i & 2) >> 1]);
    }
    for (const q of [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]) {
      idx.push(base + q[0], base + q[1], base + q[2], base + q[0], base + q[2], base + q[3]);
    }
  });
  const n = pos.length;
  const STEP = 0.01;
  const offset = [-5, -1, 3];
  const qpos = new Int16Array(n * 4);  // VEC3 SHORT, padded to a 4-byte stride
  pos.forEach((p, i) => { for (let k = 0; k < 3; k++) qpos[i * 4 + k] = Math.round(p[k] / STEP); });
  const fids = new Uint16Array(n * 2);  // SCALAR UNSIGNED_SHORT, 4-byte stride
  fid.forEach((f, i) => { fids[i * 2] = f; });
  const uvs = new Uint16Array(n * 2);  // VEC2 UNSIGNED_SHORT normalized
  uv.forEach((t, i) => { uvs[i * 2] = t[0] * 65535; uvs[i * 2 + 1] = t[1] * 65535; });
  const indices = new Uint16Array(idx);

  const bin = [];
  let binLength = 0;
  const push = (bytes) => {
    const at = binLength;
    bin.push(bytes);
    binLength += bytes.length;
    const pad = (4 - (binLength % 4)) % 4;
    if (pad) { bin.push(new Uint8Array(pad)); binLength += pad; }
    return at;
  };
  const bufferViews = [];
  let fallbackLength = 0;
  const compressed = (typed, count, stride, mode, target) => {
    const raw = new Uint8Array(typed.buffer, typed.byteOffset, typed.byteLength);
    const enc = MeshoptEncoder.encodeGltfBuffer(raw, count, stride, mode, 0);  // version 0: EXT_meshopt_compression
    const at = push(enc);
    const view = {buffer: 1, byteOffset: fallbackLength, byteLength: count * stride, target,
      extensions: {EXT_meshopt_compression: {buffer: 0, byteOffset: at, byteLength: enc.length, byteStride: stride,
        count, mode}}};
    if (mode === 'ATTRIBUTES') view.byteStride = stride;
    fallbackLength += count * stride;
    bufferViews.push(view);
    return bufferViews.length - 1;
  };
  const plain = (bytes) => {
    bufferViews.push({buffer: 0, byteOffset: push(bytes), byteLength: bytes.length});
    return bufferViews.length - 1;
  };
  const vPos = compressed(qpos, n, 8, 'ATTRIBUTES', 34962);
  const vFid = compressed(fids, n, 4, 'ATTRIBUTES', 34962);
  const vUv = compressed(uvs, n, 4, 'ATTRIBUTES', 34962);
  const vIdx = compressed(indices, indices.length, 2, 'TRIANGLES', 34963);
  const osmIds = [4242n, 9007199254740000n];
  const heights = [8, 9];
  const vOsm = plain(new Uint8Array(new BigInt64Array(osmIds).buffer));
  const vHeight = plain(new Uint8Array(new Float32Array(heights).buffer));
  const vImage = plain(new Uint8Array(fs.readFileSync(ktx2)));
  const mins = [0, 1, 2].map((k) => Math.min(...pos.map((p) => Math.round(p[k] / STEP))));
  const maxs = [0, 1, 2].map((k) => Math.max(...pos.map((p) => Math.round(p[k] / STEP))));
  const gltf = {
    asset: {version: '2.0', generator: 'citylod tests/js/loadersgl_parse.mjs'},
    extensionsUsed: ['KHR_mesh_quantization', 'EXT_meshopt_compression', 'KHR_texture_basisu', 'EXT_mesh_features',
      'EXT_structural_metadata'],
    extensionsRequired: ['KHR_mesh_quantization', 'EXT_meshopt_compression', 'KHR_texture_basisu'],
    scene: 0,
    scenes: [{nodes: [0]}],
    nodes: [{mesh: 0, matrix: [STEP, 0, 0, 0, 0, STEP, 0, 0, 0, 0, STEP, 0, ...offset, 1]}],
    meshes: [{primitives: [{attributes: {POSITION: 0, _FEATURE_ID_0: 1, TEXCOORD_0: 2}, indices: 3, material: 0,
      extensions: {EXT_mesh_features: {featureIds: [{featureCount: 2, attribute: 0, propertyTable: 0}]}}}]}],
    materials: [{pbrMetallicRoughness: {baseColorTexture: {index: 0}, metallicFactor: 0}}],
    textures: [{sampler: 0, extensions: {KHR_texture_basisu: {source: 0}}}],
    samplers: [{magFilter: 9729, minFilter: 9987}],
    images: [{bufferView: vImage, mimeType: 'image/ktx2'}],
    accessors: [
      {bufferView: vPos, componentType: 5122, count: n, type: 'VEC3', min: mins, max: maxs},
      {bufferView: vFid, componentType: 5123, count: n, type: 'SCALAR'},
      {bufferView: vUv, componentType: 5123, normalized: true, count: n, type: 'VEC2'},
      {bufferView: vIdx, componentType: 5123, count: indices.length, type: 'SCALAR'},
    ],
    bufferViews,
    buffers: [{byteLength: binLength}, {byteLength: fallbackLength, extensions: {EXT_meshopt_compression: {
      fallback: true}}}],
    extensions: {EXT_structural_metadata: {
      schema: {id: 'fixture', classes: {building: {properties: {osm_id: {type: 'SCALAR', componentType: 'INT64'},
        height: {type: 'SCALAR', componentType: 'FLOAT32'}}}}},
      propertyTables: [{class: 'building', count: 2, properties: {osm_id: {values: vOsm}, height: {values: vHeight}}}],
    }},
  };
  let json = Buffer.from(JSON.stringify(gltf));
  json = Buffer.concat([json, Buffer.alloc((4 - (json.length % 4)) % 4, 0x20)]);
  const binary = Buffer.concat(bin.map((b) => Buffer.from(b.buffer, b.byteOffset, b.byteLength)));
  const header = Buffer.alloc(12);
  header.write('glTF', 0);
  header.writeUInt32LE(2, 4);
  header.writeUInt32LE(12 + 8 + json.length + 8 + binary.length, 8);
  const chunk = (len, type) => { const h = Buffer.alloc(8); h.writeUInt32LE(len, 0); h.write(type, 4); return h; };
  fs.writeFileSync(out, Buffer.concat([header, chunk(json.length, 'JSON'), json, chunk(binary.length, 'BIN\0'),
    binary]));
  const world = pos.map((p) => p.map((c, k) => Math.round(c / STEP) * STEP + offset[k]));
  return {vertices: n, triangles: indices.length / 3, featureCount: 2, osm_id: osmIds.map(jsonValue), height: heights,
    bbox: [[0, 1, 2].map((k) => Math.min(...world.map((p) => p[k]))),
      [0, 1, 2].map((k) => Math.max(...world.map((p) => p[k])))],
    compressedBytes: binLength - fs.statSync(ktx2).size, rawBytes: fallbackLength};
}

/** meshoptimizer's encoder: the copy @loaders.gl/gltf depends on (1.x), else the hoisted one. */
function pathToMeshopt() {
  const gltfDir = packageDir('@loaders.gl/gltf');
  const nested = path.join(gltfDir, 'node_modules', 'meshoptimizer', 'meshopt_encoder.js');
  return fs.existsSync(nested) ? nested : require.resolve('meshoptimizer');
}

// --- main ---------------------------------------------------------------------------------------------------
const [cmd, ...args] = process.argv.slice(2);
const commands = {tileset: cmdTileset, texture: cmdTexture, 'fixture-glb': cmdFixtureGlb};
if (!commands[cmd]) {
  console.error(`usage: loadersgl_parse.mjs ${Object.keys(commands).join('|')} <args>`);
  process.exit(64);
}
let result;
try {
  result = await commands[cmd](...args);
} catch (e) {
  result = {errors: [String(e?.stack || e)]};
}
result.network = network;
fs.writeSync(1, `${JSON.stringify(result)}\n`);  // synchronous: process.exit would cut a piped console.log
process.exit(network.length ? 2 : result.errors?.length ? 1 : 0);
