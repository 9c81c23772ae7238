// loaders.gl in Node, offline: what tests/js/loadersgl_parse.mjs (parse every content) and
// tests/e2e/loadersgl_tileset.mjs (Tileset3D's traversal) share. Import it before loaders.gl: it installs the
// image hook @loaders.gl/images reads at import time.
//
// Offline: the Basis transcoder comes from node_modules/@loaders.gl/textures/dist/libs (loaders.gl would
// otherwise build a CDN or a relative `modules/...` URL for it), meshopt's wasm is embedded in meshoptimizer,
// workers are off, and WebP goes to sharp through loaders.gl's Node image hook. Every network attempt (fetch,
// a socket) is recorded in `network`: the drivers fail a run that made one (exit 2).
import fs from 'node:fs';
import net from 'node:net';
import path from 'node:path';
import vm from 'node:vm';
import {createRequire} from 'node:module';
import {fileURLToPath} from 'node:url';

export const require = createRequire(import.meta.url);
/** Every network attempt (a fetch, a socket to a host): a run with one fails. */
export const network = [];

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


// --- decoders from node_modules -----------------------------------------------------------------------------
/** A package's directory (their exports maps hide package.json; the main entry is in <pkg>/dist/). */
export const packageDir = (name) => path.dirname(path.dirname(require.resolve(name)));
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

/** Every file loaders.gl read, in order. */
export const fetched = [];
/** loaders.gl's fetch: local files only (a URL is the network: refused). A query is dropped as a file server
 * would: Tileset3D adds the tileset's `?v=<asset.tilesetVersion>` to every request. */
export async function fileFetch(url) {
  const u = String(url).replace(/[?#].*$/, '');
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

export async function options() {
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

export function jsonValue(v) {
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
export function contentReport(gltf) {
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
export function* tilesOf(root) {
  const stack = [[root, 0]];
  while (stack.length) {
    const [tile, depth] = stack.pop();
    yield [tile, depth];
    for (const c of tile.children || []) stack.push([c, depth + 1]);
  }
}
