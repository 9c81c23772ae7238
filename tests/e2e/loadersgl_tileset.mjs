// loaders.gl's Tileset3D (@loaders.gl/tiles: what deck.gl's Tile3DLayer drives) on our tilesets, in Node, offline
// (tests/js/loadersgl_client.mjs). The cameras are deck.gl WebMercatorViewports (@deck.gl/core), the kind
// Tile3DLayer hands the tileset; the traversal is the one Tile3DLayer runs: selectTiles(viewport) again until every
// selected tile is loaded and the selection stops changing.
//
//   node tests/e2e/loadersgl_tileset.mjs --tileset DIR/tileset.json [--load-all] [--cameras JSON] [--max-sse N]
//
// --load-all   every tile of the tree loads (Tile3D.loadContent, as a traversal would); per tile the uri, depth,
//              the geometric error the client gives it (lodMetricValue: root / 2^level for implicit tiles), the
//              triangles its glTF holds, and load errors.
// --cameras    a JSON list of CesiumJS cameras ({name, lon, lat, height, heading, pitch, fovyDeg, widthPx,
//              heightPx}); per camera the content uris of the tiles selected for rendering.
// Prints one JSON object; exit 2 if a network access was attempted, 1 on an error.
import fs from 'node:fs';
import path from 'node:path';
import {contentReport, network, options, tilesOf} from '../js/loadersgl_client.mjs';

const {load} = await import('@loaders.gl/core');
const {Tiles3DLoader} = await import('@loaders.gl/3d-tiles');
const {Tileset3D} = await import('@loaders.gl/tiles');
const {WebMercatorViewport} = await import('@deck.gl/core');
const {getDistanceScales} = await import('@math.gl/web-mercator');

// loaders.gl's screen-space error divides by 1.15 (2 tan 30°: its frame state assumes a 60° field of view),
// CesiumJS's by 2 tan(fovy / 2). The camera keeps CesiumJS's fovy (the same frustum), so the same threshold in
// CesiumJS's terms is maxSse * 2 tan(fovy / 2) / 1.15.
const LOADERSGL_SSE_DENOMINATOR = 1.15;

function arg(name, fallback = null) {
  const i = process.argv.indexOf(name);
  return i < 0 ? fallback : process.argv[i + 1];
}

/** A WebMercatorViewport seeing what a CesiumJS camera sees: deck.gl's camera looks at a ground point (the
 * centre), pitch from the vertical, bearing clockwise from north, its distance to the centre `altitude` viewport
 * heights in pixels at the centre's scale. */
function viewport(cam) {
  const down = -cam.pitch;  // CesiumJS: degrees below the horizon, 90 straight down
  if (!(down > 0.5)) throw new Error(`camera ${cam.name}: looks above the horizon, it has no ground centre`);
  const r = Math.PI / 180;
  const ahead = cam.height / Math.tan(down * r);  // metres from below the camera to where the view axis meets the ground
  const distance = cam.height / Math.sin(down * r);
  const lat0 = cam.lat * r;
  // a local step on the sphere is enough at these distances (< 10 km)
  const R = 6378137;
  const latitude = cam.lat + (ahead * Math.cos(cam.heading * r)) / R / r;
  const longitude = cam.lon + (ahead * Math.sin(cam.heading * r)) / (R * Math.cos(lat0)) / r;
  const altitude = 1 / (2 * Math.tan((cam.fovyDeg * r) / 2));  // what WebMercatorViewport derives from fovy
  const pixelsPerMeter = (altitude * cam.heightPx) / distance;
  const unitsPerMeter = getDistanceScales({longitude, latitude}).unitsPerMeter[0];  // at zoom 0
  const zoom = Math.log2(pixelsPerMeter / unitsPerMeter);
  return new WebMercatorViewport({id: cam.name, width: cam.widthPx, height: cam.heightPx, longitude, latitude,
    zoom, pitch: 90 - down, bearing: cam.heading, fovy: cam.fovyDeg, nearZMultiplier: 0.01, farZMultiplier: 10});
}

function uriOf(tile, base) {
  return tile.contentUrl ? path.relative(base, tile.contentUrl.replace(/[?#].*$/, '')).split(path.sep).join('/') : null;
}

async function openTileset(file, maxSse, errors) {
  const opts = await options();
  const tilesetJson = await load(file, Tiles3DLoader, {...opts, '3d-tiles': {...opts['3d-tiles'], isTileset: true}});
  const tileset = new Tileset3D(tilesetJson, {
    loadOptions: {...opts, '3d-tiles': {...opts['3d-tiles'], isTileset: false}},
    maximumScreenSpaceError: maxSse,
    throttleRequests: false,
    maximumMemoryUsage: 4096,
    debounceTime: 0,
    onTileError: (tile, message, url) => errors.push(`${url}: ${message}`),
  });
  await tileset.tilesetInitializationPromise;
  return tileset;
}

async function loadAll(file, base, errors) {
  const tileset = await openTileset(file, 16, errors);
  const tiles = [];
  for (const [tile, depth] of tilesOf(tileset.root)) {
    const uri = uriOf(tile, base);
    if (!uri) continue;
    try {
      await tile.loadContent();
    } catch (e) {
      errors.push(`${uri}: ${e?.message || e}`);
      continue;
    }
    const gltf = tile.content?.gltf;
    const rep = gltf ? contentReport(gltf) : null;
    tiles.push({uri, depth, leaf: !(tile.children || []).length, error: tile.lodMetricValue,
      loaded: tile.contentAvailable === true, triangles: rep ? rep.triangles : null,
      images: rep ? rep.images.length : 0});
  }
  return tiles;
}

async function views(file, base, cams, maxSse, errors) {
  const out = [];
  for (const cam of cams) {
    const sse = (maxSse * 2 * Math.tan((cam.fovyDeg * Math.PI) / 360)) / LOADERSGL_SSE_DENOMINATOR;
    const tileset = await openTileset(file, sse, errors);  // a fresh client per camera: no tile from another view
    const vp = viewport(cam);
    let previous = '';
    let frames = 0;
    for (; frames < 400; frames++) {
      await tileset.selectTiles([vp]);
      await new Promise((res) => setTimeout(res, 10));
      const now = tileset.selectedTiles.map((t) => t.id).sort().join(',');
      if (tileset.isLoaded() && now === previous && !tileset._requestedTiles?.length) break;
      previous = now;
    }
    out.push({name: cam.name, frames, settled: frames < 400, maxSse: sse,
      viewport: {longitude: vp.longitude, latitude: vp.latitude, zoom: vp.zoom, pitch: vp.pitch, bearing: vp.bearing},
      tiles: tileset.selectedTiles.map((t) => ({uri: uriOf(t, base), depth: t.depth, sse: t._screenSpaceError}))
        .filter((t) => t.uri)});
  }
  return out;
}

const errors = [];
const result = {};
try {
  const file = path.resolve(arg('--tileset'));
  const base = path.dirname(file);
  if (process.argv.includes('--load-all')) result.loadAll = await loadAll(file, base, errors);
  const cams = arg('--cameras');
  if (cams) result.views = await views(file, base, JSON.parse(cams), Number(arg('--max-sse', '16')), errors);
} catch (e) {
  errors.push(String(e?.stack || e));
}
result.errors = errors;
result.network = network;
fs.writeSync(1, `${JSON.stringify(result)}\n`);  // synchronous: process.exit would cut a piped console.log
process.exit(network.length ? 2 : errors.length ? 1 : 0);
