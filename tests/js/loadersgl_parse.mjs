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
// Offline (tests/js/loadersgl_client.mjs): every network attempt fails the run (exit 2).

import fs from 'node:fs';
import path from 'node:path';
import {contentReport, fetched, jsonValue, network, options, packageDir, require, tilesOf} from './loadersgl_client.mjs';

const {load, parse} = await import('@loaders.gl/core');
const {Tiles3DLoader} = await import('@loaders.gl/3d-tiles');
const {BasisLoader} = await import('@loaders.gl/textures');

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
