// citylod roof gallery: the whole tileset in one oblique view, with a legend of the roof shapes it contains.
// Fully offline like the viewer (no ion token, no imagery, no terrain). Open /viewer/gallery.html on
// `python -m exporter serve`; ?tileset=URL loads another tileset.
//
// The legend is built from the features of the loaded tile content (Cesium3DTileContent.featuresLength,
// getFeature(i).getProperty('roof_shape')), one entry per shape with its number of buildings; clicking an
// entry highlights that shape's buildings (the others turn translucent).
// window.citylodGallery is the hook the e2e test (tests/e2e/gallery_e2e.mjs) reads; keep its fields stable.
(function () {
  'use strict';

  const log = (...args) => console.log('[gallery]', ...args);
  const HIGHLIGHT = '#ff6a00';
  // The OSM roof:shape catalogue, only to order the legend; shapes outside it are listed after, by name.
  const CATALOGUE = [
    'flat', 'skillion', 'gabled', 'half-hipped', 'hipped', 'side_hipped', 'side_half-hipped', 'hipped-and-gabled',
    'pyramidal', 'cone', 'dome', 'onion', 'round', 'gambrel', 'mansard', 'saltbox', 'sawtooth', 'butterfly',
    'crosspitched', 'gabled_height_moved',
  ];
  const NONE = '(none)'; // a feature without a roof_shape value
  // Camera: looking north-north-east, 50° down; the sun from the west-south-west (the viewer's left), 40° up,
  // so that slopes facing different ways get clearly different shades and pitched roofs read at a glance.
  const VIEW = { heading: 15, pitch: -50 };
  const SUN = { azimuth: 245, elevation: 40 };
  const AMBIENT = 0.2; // share of the light that reaches faces turned away from the sun

  const statusEl = document.getElementById('status');
  const legendEl = document.getElementById('legend');
  const panelEl = document.getElementById('panel');
  const pickedEl = document.getElementById('picked');

  const gallery = (window.citylodGallery = {
    viewer: null,
    tileset: null,
    ready: false, // tileset loaded, camera framed, every tile of the view loaded, legend built
    error: null,
    shapes: {}, // roof_shape -> number of buildings (distinct osm_type/osm_id)
    featureCount: 0, // distinct features over all loaded tile content
    tilesWithContent: 0, // tiles whose content the counts were read from
    selected: null, // the highlighted shape, or null
  });

  const viewer = window.citylodCommon.makeViewer('cesium', gallery, '[gallery]');
  const scene = viewer.scene;
  const camera = scene.camera;
  scene.globe.enableLighting = false; // the ground stays one flat colour; only the buildings are shaded
  scene.fog.enabled = false;

  // --- loading ---------------------------------------------------------------------------------------------
  const tilesetUrl = window.citylodCommon.tilesetUrl();

  async function load() {
    statusEl.textContent = `loading ${tilesetUrl} …`;
    const tileset = await Cesium.Cesium3DTileset.fromUrl(tilesetUrl);
    gallery.tileset = tileset;
    tileset.tileFailed.addEventListener((e) => console.error('[gallery] tile failed', e.url, e.message));
    scene.primitives.add(tileset);

    const centre = Cesium.Ellipsoid.WGS84.cartesianToCartographic(tileset.boundingSphere.center);
    scene.light = sunLight(centre, SUN.azimuth, SUN.elevation);
    tileset.customShader = hillshade();

    frameAll();
    const settled = await settle();
    if (!settled.loaded) log(`tiles still loading after ${settled.ms} ms; counting what is there`);
    frameAll(); // the canvas may have been resized while loading
    await settle();
    countShapes();
    buildLegend();
    gallery.ready = true;
    log('ready:', gallery.featureCount, 'features,', Object.keys(gallery.shapes).length, 'roof shapes');
  }

  load().catch((err) => {
    gallery.error = String(err && err.message ? err.message : err);
    statusEl.textContent = `could not load ${tilesetUrl}: ${gallery.error}`;
    console.error('[gallery] tileset load failed:', gallery.error);
  });

  // A directional light from azimuth/elevation (degrees; azimuth clockwise from north) at `where`.
  function sunLight(where, azimuth, elevation) {
    const az = Cesium.Math.toRadians(azimuth);
    const el = Cesium.Math.toRadians(elevation);
    const toSun = new Cesium.Cartesian3(Math.sin(az) * Math.cos(el), Math.cos(az) * Math.cos(el), Math.sin(el));
    const enu = Cesium.Transforms.eastNorthUpToFixedFrame(Cesium.Cartographic.toCartesian(where));
    const dir = Cesium.Matrix4.multiplyByPointAsVector(enu, toSun, new Cesium.Cartesian3());
    Cesium.Cartesian3.negate(dir, dir); // the light travels away from the sun
    Cesium.Cartesian3.normalize(dir, dir);
    return new Cesium.DirectionalLight({ direction: dir, intensity: 2.2 });
  }

  // Plain Lambert shading from scene.light over a dim ambient term, instead of CesiumJS's physically based
  // lighting, whose image-based ambient light washes the faces of a roof out to nearly one shade. The
  // material colour (the roof and wall colours of the tile, and any style colour) is kept.
  function hillshade() {
    return new Cesium.CustomShader({
      lightingModel: Cesium.LightingModel.UNLIT,
      fragmentShaderText: `
        void fragmentMain(FragmentInput fsInput, inout czm_modelMaterial material) {
          vec3 n = normalize(fsInput.attributes.normalEC);
          float lit = max(dot(n, czm_lightDirectionEC), 0.0);
          material.diffuse *= ${AMBIENT.toFixed(3)} + ${(1 - AMBIENT).toFixed(3)} * 1.15 * lit;
        }`,
    });
  }

  // --- camera ----------------------------------------------------------------------------------------------
  // The eight corners of the tileset's bounding region (the box around its bounding sphere when the root
  // volume is not a region).
  function tilesetCorners(tileset) {
    const bv = tileset.root.boundingVolume;
    const pts = [];
    if (bv && bv.rectangle && bv.minimumHeight !== undefined) {
      const r = bv.rectangle;
      for (const lon of [r.west, r.east]) {
        for (const lat of [r.south, r.north]) {
          for (const h of [bv.minimumHeight, bv.maximumHeight]) pts.push(Cesium.Cartesian3.fromRadians(lon, lat, h));
        }
      }
      return pts;
    }
    const s = tileset.boundingSphere;
    const enu = Cesium.Transforms.eastNorthUpToFixedFrame(s.center);
    for (const x of [-1, 1]) {
      for (const y of [-1, 1]) {
        for (const z of [-1, 1]) {
          const v = new Cesium.Cartesian3(x * s.radius, y * s.radius, z * s.radius);
          pts.push(Cesium.Matrix4.multiplyByPoint(enu, v, new Cesium.Cartesian3()));
        }
      }
    }
    return pts;
  }

  // The part of the canvas not covered by the panel, the credits or the attribution (CSS pixels).
  function freeArea() {
    const c = scene.canvas.getBoundingClientRect();
    const p = panelEl.getBoundingClientRect();
    const pad = 24;
    let x0 = pad;
    if (p.width > 0 && p.right < c.width * 0.5) x0 = p.right - c.left + pad;
    return { x0, y0: pad, x1: c.width - pad, y1: c.height - 40 };
  }

  // Oblique view (VIEW.heading/pitch) that fits every corner of the tileset into the free part of the canvas:
  // a few rounds of "look at the centre from `range`, move sideways by `right`/`up` metres", each correcting
  // range and offsets by how far the projected corners miss the free area.
  function frameAll(heading = VIEW.heading, pitch = VIEW.pitch) {
    const tileset = gallery.tileset;
    if (!tileset) return null;
    const corners = tilesetCorners(tileset);
    const centre = Cesium.BoundingSphere.fromPoints(corners).center;
    const hpr = new Cesium.HeadingPitchRange(Cesium.Math.toRadians(heading), Cesium.Math.toRadians(pitch), 0);
    const area = freeArea();
    const aw = area.x1 - area.x0;
    const ah = area.y1 - area.y0;
    let range = 3 * tileset.boundingSphere.radius + 50;
    let right = 0;
    let up = 0;
    let fit = null;
    for (let round = 0; round < 30; round++) {
      hpr.range = range;
      camera.lookAt(centre, hpr);
      camera.lookAtTransform(Cesium.Matrix4.IDENTITY);
      camera.moveRight(right);
      camera.moveUp(up);
      let x0 = Infinity;
      let y0 = Infinity;
      let x1 = -Infinity;
      let y1 = -Infinity;
      let behind = false;
      for (const p of corners) {
        const w = Cesium.SceneTransforms.worldToWindowCoordinates(scene, p);
        if (!w) {
          behind = true;
          break;
        }
        x0 = Math.min(x0, w.x);
        x1 = Math.max(x1, w.x);
        y0 = Math.min(y0, w.y);
        y1 = Math.max(y1, w.y);
      }
      if (behind) {
        range *= 2;
        continue;
      }
      fit = { x0, y0, x1, y1 };
      const scale = Math.max((x1 - x0) / aw, (y1 - y0) / ah);
      const px = camera.frustum.getPixelDimensions(scene.canvas.clientWidth, scene.canvas.clientHeight, range, 1,
        new Cesium.Cartesian2());
      right += ((x0 + x1) / 2 - (area.x0 + area.x1) / 2) * px.x;
      up -= ((y0 + y1) / 2 - (area.y0 + area.y1) / 2) * px.y;
      range *= scale;
      const off = Math.hypot((x0 + x1) / 2 - (area.x0 + area.x1) / 2, (y0 + y1) / 2 - (area.y0 + area.y1) / 2);
      if (Math.abs(scale - 1) < 0.005 && off < 1) break;
    }
    gallery.frame = { heading, pitch, range, right, up, area, fit };
    return gallery.frame;
  }

  function settle() {
    return window.citylodCommon.settle(scene, () => gallery.tileset);
  }

  // --- the legend ------------------------------------------------------------------------------------------
  // Every loaded content of a tile: composite and multiple contents (3D Tiles 1.1) hold inner contents.
  function contentsOf(content, out = []) {
    if (!content) return out;
    const inner = content.innerContents;
    if (inner && inner.length) {
      for (const c of inner) contentsOf(c, out);
    } else {
      out.push(content);
    }
    return out;
  }

  function forEachFeature(fn) {
    const tileset = gallery.tileset;
    const stack = tileset && tileset.root ? [tileset.root] : [];
    let tiles = 0;
    while (stack.length) {
      const tile = stack.pop();
      if (tile.contentReady && tile.content) {
        let has = false;
        for (const content of contentsOf(tile.content)) {
          const n = content.featuresLength || 0;
          for (let i = 0; i < n; i++) fn(content.getFeature(i));
          has = has || n > 0;
        }
        if (has) tiles += 1;
      }
      for (const child of tile.children || []) stack.push(child);
    }
    return tiles;
  }

  // Distinct buildings per roof shape: a feature is counted once even if several loaded tiles (e.g. a parent
  // and its children) carry it.
  function countShapes() {
    const seen = new Set();
    const shapes = {};
    gallery.tilesWithContent = forEachFeature((f) => {
      const key = `${f.getProperty('osm_type')}/${f.getProperty('osm_id')}`;
      if (seen.has(key)) return;
      seen.add(key);
      const v = f.getProperty('roof_shape');
      const shape = v === undefined || v === null || v === '' ? NONE : String(v);
      shapes[shape] = (shapes[shape] || 0) + 1;
    });
    gallery.shapes = shapes;
    gallery.featureCount = seen.size;
    const n = Object.keys(shapes).length;
    statusEl.textContent = `${seen.size} buildings · ${n} roof shape${n === 1 ? '' : 's'} · ` +
      `${gallery.tilesWithContent} tile${gallery.tilesWithContent === 1 ? '' : 's'}`;
  }

  function order(a, b) {
    const ia = CATALOGUE.indexOf(a);
    const ib = CATALOGUE.indexOf(b);
    if (ia >= 0 && ib >= 0) return ia - ib;
    if (ia >= 0 || ib >= 0) return ia >= 0 ? -1 : 1;
    return a < b ? -1 : a > b ? 1 : 0;
  }

  function legendItem(shape, count, label, cls) {
    const li = document.createElement('li');
    li.dataset.shape = shape;
    li.tabIndex = 0;
    li.setAttribute('role', 'button');
    if (cls) li.className = cls;
    const name = document.createElement('span');
    name.className = 'shape';
    name.textContent = label;
    const num = document.createElement('span');
    num.className = 'count';
    num.textContent = String(count);
    li.append(name, num);
    const act = () => {
      pickedEl.hidden = true;
      highlight(shape === '' || gallery.selected === shape ? null : shape);
    };
    li.addEventListener('click', act);
    li.addEventListener('keydown', (e) => {
      if (e.key === 'Enter' || e.key === ' ') {
        e.preventDefault();
        act();
      }
    });
    return li;
  }

  function buildLegend() {
    legendEl.replaceChildren();
    legendEl.append(legendItem('', gallery.featureCount, 'all', 'all'));
    for (const shape of Object.keys(gallery.shapes).sort(order)) {
      legendEl.append(legendItem(shape, gallery.shapes[shape], shape));
    }
  }

  // Highlight the buildings of one roof shape (null: back to plain colours). A style, not per-feature
  // colours, so tiles loaded later are coloured too.
  function highlight(shape) {
    const tileset = gallery.tileset;
    if (!tileset) return;
    gallery.selected = shape || null;
    for (const li of legendEl.children) {
      li.classList.toggle('selected', gallery.selected !== null && li.dataset.shape === gallery.selected);
    }
    if (!gallery.selected) {
      tileset.style = undefined;
      tileset.colorBlendMode = Cesium.Cesium3DTileColorBlendMode.HIGHLIGHT;
      log('highlight off');
      return;
    }
    const cond = gallery.selected === NONE
      ? '${roof_shape} === undefined || ${roof_shape} === null || ${roof_shape} === ""'
      : '${roof_shape} === ' + JSON.stringify(gallery.selected);
    tileset.colorBlendMode = Cesium.Cesium3DTileColorBlendMode.MIX;
    tileset.colorBlendAmount = 0.7;
    tileset.style = new Cesium.Cesium3DTileStyle({
      color: { conditions: [[cond, `color('${HIGHLIGHT}')`], ['true', "color('#ffffff', 0.25)"]] },
    });
    log('highlight', gallery.selected, gallery.shapes[gallery.selected] || 0);
  }

  // Clicking a building highlights its roof shape (and names it); clicking the ground or the same shape again
  // clears the highlight.
  const handler = new Cesium.ScreenSpaceEventHandler(scene.canvas);
  handler.setInputAction((click) => {
    if (!gallery.ready) return;
    const picked = scene.pick(click.position);
    if (!(picked instanceof Cesium.Cesium3DTileFeature)) {
      pickedEl.hidden = true;
      highlight(null);
      return;
    }
    const v = picked.getProperty('roof_shape');
    const shape = v === undefined || v === null || v === '' ? NONE : String(v);
    const name = picked.getProperty('name');
    const id = `${picked.getProperty('osm_type')} ${picked.getProperty('osm_id')}`;
    pickedEl.textContent = `${name ? `${name} (${id})` : id}: ${shape}`;
    pickedEl.hidden = false;
    highlight(gallery.selected === shape ? null : shape);
  }, Cesium.ScreenSpaceEventType.LEFT_CLICK);

  // Keep the whole tileset in view when the window changes size.
  window.addEventListener('resize', () => {
    if (gallery.ready) frameAll();
  });
})();
