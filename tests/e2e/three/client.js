// The three.js client of the e2e tests: NASA-AMMOS 3DTilesRendererJS (TilesRenderer with its ImplicitTilingPlugin
// and GLTFExtensionsPlugin) on three.js, with three's own KTX2Loader and MeshoptDecoder, as a three.js user sets
// it up. It computes implicit tiles' volumes and errors from the root alone (its SUBTREELoader ignores the
// subtrees' TILE_BOUNDING_REGION / TILE_GEOMETRIC_ERROR), which is what tests/e2e/test_three_client.py checks.
// window.t3 holds what three_e2e.mjs calls; every function returns plain JSON.
import * as THREE from 'three';
import { TilesRenderer, WGS84_ELLIPSOID, CAMERA_FRAME } from '3d-tiles-renderer';
import { ImplicitTilingPlugin, GLTFExtensionsPlugin } from '3d-tiles-renderer/plugins';
import { KTX2Loader } from 'three/addons/loaders/KTX2Loader.js';
import { MeshoptDecoder } from 'three/addons/libs/meshopt_decoder.module.js';

const R = THREE.MathUtils.degToRad;
const CONTENT = /content\/(\d+)\/(\d+)\/(\d+)\.glb$/;
const frame = () => new Promise((resolve) => setTimeout(resolve, 20));

let renderer;
let scene;
let camera;
let tiles;
const loadErrors = [];
const loaded = new Set(); // content uris whose model was parsed

const uriOf = (tile) => {
  const u = tile.content && tile.content.uri ? tile.content.uri : '';
  const m = CONTENT.exec(u);
  return m ? `content/${m[1]}/${m[2]}/${m[3]}.glb` : u;
};

function open({ tileset, width, height }) {
  const canvas = document.createElement('canvas');
  document.body.appendChild(canvas);
  renderer = new THREE.WebGLRenderer({ canvas, antialias: false });
  renderer.setPixelRatio(1);
  renderer.setSize(width, height, false);
  scene = new THREE.Scene();
  scene.add(new THREE.AmbientLight(0xffffff, 1.5));
  camera = new THREE.PerspectiveCamera(60, width / height, 1, 1e8);

  const ktx2 = new KTX2Loader().setTranscoderPath('/__three/node_modules/three/examples/jsm/libs/basis/')
    .detectSupport(renderer);
  tiles = new TilesRenderer(tileset);
  tiles.registerPlugin(new ImplicitTilingPlugin());
  tiles.registerPlugin(new GLTFExtensionsPlugin({ metadata: true, rtc: true, ktxLoader: ktx2,
    meshoptDecoder: MeshoptDecoder }));
  tiles.addEventListener('load-error', (e) => loadErrors.push(`${e.url}: ${e.error && e.error.message}`));
  tiles.addEventListener('load-model', (e) => loaded.add(uriOf(e.tile)));
  tiles.setCamera(camera);
  tiles.setResolution(camera, width, height);
  scene.add(tiles.group);
}

function update(render) {
  camera.updateMatrixWorld();
  tiles.update();
  if (render) renderer.render(scene, camera);
}

// Until nothing is queued, downloading, parsing or being expanded and the visible tiles stay the same.
async function settle(timeoutMs) {
  const t0 = performance.now();
  let last = '';
  let same = 0;
  while (performance.now() - t0 < timeoutMs) {
    update(false);
    await frame();
    const busy = tiles.downloadQueue.running || tiles.parseQueue.running || tiles.processNodeQueue.running ||
      tiles.stats.queued || tiles.stats.downloading || tiles.stats.parsing;
    const key = [...tiles.visibleTiles].map(uriOf).sort().join('|');
    same = !busy && tiles.root && key === last ? same + 1 : 0;
    last = key;
    if (same >= 5) {
      update(true);
      return { loaded: true, ms: Math.round(performance.now() - t0) };
    }
  }
  update(true);
  return { loaded: false, ms: Math.round(performance.now() - t0) };
}

// What is drawn: each visible tile with its level, the error the client gives it and its triangles.
function drawn() {
  const out = [];
  for (const tile of tiles.visibleTiles) {
    let triangles = 0;
    const textures = new Set();
    let fewestMips = Infinity;
    const s = tile.engineData.scene;
    if (s) {
      s.traverse((o) => {
        if (!o.isMesh) return;
        triangles += (o.geometry.index ? o.geometry.index.count : o.geometry.attributes.position.count) / 3;
        const map = o.material && o.material.map;
        if (map && !textures.has(map)) {
          textures.add(map);
          fewestMips = Math.min(fewestMips, map.isCompressedTexture ? map.mipmaps.length : 0);
        }
      });
    }
    out.push({ uri: uriOf(tile), geometricError: tile.geometricError, triangles, leaf: tile.children.length === 0,
      textures: textures.size, fewestMips: textures.size ? fewestMips : null });
  }
  return out.sort((a, b) => (a.uri < b.uri ? -1 : 1));
}

// Per building of a loaded tile (its features grouped by building_osm_type/id: an outline with its parts, or a
// block), how far its farthest vertex lies from the client's own volume for the tile (tile.engineData
// .boundingVolume, what it culls with), against the building's half-extent east and north.
const overhangs = new Map(); // uri -> {features, buildings, worst, beyond: [{building, overhang, half}]}
function groupsOf(mesh) {
  const { meshFeatures, structuralMetadata } = mesh.userData;
  if (!meshFeatures || !structuralMetadata) return (f) => `feature ${f}`;
  const table = meshFeatures.getFeatureInfo()[0].propertyTable;
  const cache = new Map();
  return (f) => {
    if (!cache.has(f)) {
      const row = structuralMetadata.getPropertyTableData(table, f);
      cache.set(f, `${row.building_osm_type} ${row.building_osm_id}`);
    }
    return cache.get(f);
  };
}
function measureContainment() {
  const groupInv = new THREE.Matrix4().copy(tiles.group.matrixWorld).invert();
  const sphere = new THREE.Sphere();
  tiles.getBoundingSphere(sphere);
  const carto = WGS84_ELLIPSOID.getPositionToCartographic(sphere.center, {});
  const enuInv = WGS84_ELLIPSOID.getEastNorthUpFrame(carto.lat, carto.lon, 0, new THREE.Matrix4()).invert();
  const p = new THREE.Vector3();
  const q = new THREE.Vector3();
  for (const tile of tiles.visibleTiles) {
    const uri = uriOf(tile);
    const s = tile.engineData.scene;
    if (!s || overhangs.has(uri)) continue;
    const volume = tile.engineData.boundingVolume;
    const per = new Map(); // building -> [overhang, minE, minN, maxE, maxN]
    const features = new Set();
    s.updateMatrixWorld(true);
    s.traverse((o) => {
      if (!o.isMesh) return;
      const pos = o.geometry.attributes.position;
      const fid = o.geometry.getAttribute('_feature_id_0');
      const group = groupsOf(o);
      const m = new THREE.Matrix4().multiplyMatrices(groupInv, o.matrixWorld);
      for (let i = 0; i < pos.count; ++i) {
        p.fromBufferAttribute(pos, i).applyMatrix4(m);
        q.copy(p).applyMatrix4(enuInv);
        const f = fid ? fid.getX(i) : -1;
        features.add(`${o.uuid} ${f}`);
        const g = group(f);
        let r = per.get(g);
        if (!r) per.set(g, (r = [0, Infinity, Infinity, -Infinity, -Infinity]));
        r[0] = Math.max(r[0], volume.distanceToPoint(p));
        r[1] = Math.min(r[1], q.x);
        r[2] = Math.min(r[2], q.y);
        r[3] = Math.max(r[3], q.x);
        r[4] = Math.max(r[4], q.y);
      }
    });
    const rec = { features: features.size, buildings: per.size, worst: 0, beyond: [] };
    for (const [g, r] of per) {
      const half = Math.hypot((r[3] - r[1]) / 2, (r[4] - r[2]) / 2);
      rec.worst = Math.max(rec.worst, r[0]);
      if (r[0] > half + 0.05) rec.beyond.push({ building: g, overhang: r[0], half });
    }
    overhangs.set(uri, rec);
  }
}

// The whole tileset in view from above, then every depth in turn (maxDepth 1, 2, ...) with an error target of 0,
// so that every tile of the tree is drawn once; the last step draws the leaves.
async function loadEverything(timeoutMs) {
  const sphere = new THREE.Sphere();
  await settle(timeoutMs);
  tiles.getBoundingSphere(sphere);
  const up = sphere.center.clone().normalize();
  const dist = (1.3 * sphere.radius) / Math.sin(R(camera.fov) / 2);
  camera.position.copy(sphere.center).addScaledVector(up, dist);
  camera.up.set(0, 0, 1);
  camera.lookAt(sphere.center);
  camera.near = Math.max(1, dist - 2 * sphere.radius);
  camera.far = dist + 2 * sphere.radius;
  camera.updateProjectionMatrix();
  tiles.errorTarget = 0;
  const depths = [];
  let previous = '';
  for (let depth = 1; depth < 64; ++depth) {
    tiles.maxDepth = depth;
    const settled = await settle(timeoutMs);
    measureContainment();
    const d = drawn();
    const errors = Object.fromEntries(d.map((t) => [t.uri, t.geometricError]));
    depths.push({ depth, settled, tiles: d.map((t) => t.uri), errors });
    const key = d.map((t) => t.uri).join('|');
    if (d.length && d.every((t) => t.leaf) && key === previous) break;
    previous = key;
  }
  tiles.maxDepth = Infinity;
  const settled = await settle(timeoutMs);
  measureContainment();
  return { depths, settled, leaves: drawn(), renderedTriangles: renderer.info.render.triangles };
}

// A CesiumJS camera (degrees, metres above the ellipsoid, no roll) with CesiumJS's vertical field of view,
// aspect and drawing buffer, and the tiles the client draws from it at errorTarget maxSse.
async function view(cam, maxSse, timeoutMs) {
  renderer.setSize(cam.widthPx, cam.heightPx, false);
  tiles.setResolution(camera, cam.widthPx, cam.heightPx);
  camera.fov = cam.fovyDeg;
  camera.aspect = cam.widthPx / cam.heightPx;
  camera.near = 0.5;
  camera.far = 1e7;
  camera.updateProjectionMatrix();
  WGS84_ELLIPSOID.getObjectFrame(R(cam.lat), R(cam.lon), cam.height, R(cam.heading), R(cam.pitch), 0, camera.matrix,
    CAMERA_FRAME);
  camera.matrix.decompose(camera.position, camera.quaternion, camera.scale);
  tiles.errorTarget = maxSse;
  tiles.maxDepth = Infinity;
  const settled = await settle(timeoutMs);
  measureContainment();
  return { name: cam.name, settled, tiles: drawn(), renderedTriangles: renderer.info.render.triangles };
}

// Straight down at (lon, lat) from `top` + 200 m: the first hit's feature and its property-table row.
function pick(lon, lat, top) {
  const origin = WGS84_ELLIPSOID.getCartographicToPosition(R(lat), R(lon), top + 200, new THREE.Vector3());
  const below = WGS84_ELLIPSOID.getCartographicToPosition(R(lat), R(lon), top - 400, new THREE.Vector3());
  origin.applyMatrix4(tiles.group.matrixWorld);
  below.applyMatrix4(tiles.group.matrixWorld);
  const raycaster = new THREE.Raycaster(origin, below.sub(origin).normalize());
  const hit = raycaster.intersectObject(tiles.group, true)[0];
  if (!hit) return null;
  const { meshFeatures, structuralMetadata } = hit.object.userData;
  if (!meshFeatures || !structuralMetadata) return { distance: hit.distance, metadata: false };
  const ids = meshFeatures.getFeatures(hit.faceIndex, hit.barycoord);
  const info = meshFeatures.getFeatureInfo()[0];
  const row = structuralMetadata.getPropertyTableData(info.propertyTable, ids[0]);
  const props = {};
  for (const [k, v] of Object.entries(row)) props[k] = typeof v === 'bigint' ? v.toString() : v;
  return { distance: hit.distance, feature: ids[0], properties: props };
}

function report() {
  return {
    loadErrors,
    loaded: [...loaded].sort(),
    containment: Object.fromEntries([...overhangs].sort()),
    rootGeometricError: tiles.root ? tiles.root.geometricError : null,
    stats: { ...tiles.stats },
  };
}

window.t3 = { open, settle, loadEverything, view, pick, report, ready: true };
