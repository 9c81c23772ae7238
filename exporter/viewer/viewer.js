// citylod viewer: one 3D Tiles 1.1 tileset in CesiumJS, fully offline (no ion token, no imagery, no terrain).
// Click a building to see the properties stored in its EXT_structural_metadata property table.
// window.citylod is the hook the e2e test (tests/e2e/viewer_e2e.mjs) drives; keep its fields stable.
(function () {
  'use strict';

  const log = (...args) => console.log('[citylod]', ...args);
  const HIGHLIGHT = Cesium.Color.fromCssColorString('#ff6a00');
  const statusEl = document.getElementById('status');
  const titleEl = document.getElementById('props-title');
  const hintEl = document.getElementById('props-hint');
  const propsEl = document.getElementById('props');

  const citylod = (window.citylod = {
    viewer: null,
    tileset: null,
    ready: false, // the tileset is added to the scene and the camera is on it
    allTilesLoaded: false, // true after tileset.allTilesLoaded, false again while tiles are requested
    tileLoads: 0, // tileLoad events (tiles with content that finished loading)
    tileFailures: 0,
    picks: 0, // clicks handled, so a test can tell "picked nothing" from "not clicked yet"
    lastPicked: null, // properties of the selected feature, or null
    error: null,
    exaggeration: false, // landmark exaggeration on (setExaggeration, the checkbox or ?exaggerate=1)
    lookAt,
    stats,
    setExaggeration,
  });

  const viewer = window.citylodCommon.makeViewer('cesium', citylod, '[citylod]');
  const scene = viewer.scene;
  // The sun follows the clock; pin it to a summer forenoon so walls are lit the same way on every load.
  viewer.clock.currentTime = Cesium.JulianDate.fromIso8601('2024-06-21T09:00:00Z');

  // --- loading ---------------------------------------------------------------------------------------------
  const tilesetUrl = window.citylodCommon.tilesetUrl();

  async function load() {
    statusEl.textContent = `loading ${tilesetUrl} …`;
    const tileset = await Cesium.Cesium3DTileset.fromUrl(tilesetUrl);
    citylod.tileset = tileset;
    log('tileset', tilesetUrl, 'version', tileset.asset.version, tileset.asset.tilesetVersion || '');

    tileset.tileLoad.addEventListener((tile) => {
      citylod.tileLoads += 1;
      log('tile loaded', tile.content ? tile.content.url : '(no content)');
    });
    tileset.tileVisible.addEventListener((tile) => {
      if (!tile.content) return;
      const t = tally(tile.content);
      for (const k in t) frameKinds[k] += t[k];
    });
    tileset.tileFailed.addEventListener((e) => {
      citylod.tileFailures += 1;
      console.error('[citylod] tile failed', e.url, e.message);
    });
    // loadProgress fires whenever the request/processing counts change: anything pending means "not loaded".
    tileset.loadProgress.addEventListener((pending, processing) => {
      if (pending > 0 || processing > 0) citylod.allTilesLoaded = false;
    });
    tileset.allTilesLoaded.addEventListener(() => {
      citylod.allTilesLoaded = true;
      const s = stats();
      log(`all tiles loaded: ${s.tilesWithContent} tiles with content, ${s.triangles} triangles,`,
        `${s.features} features`);
    });

    tileset.customShader = citylod.exaggeration ? landmarkShader() : undefined;
    scene.primitives.add(tileset);
    // Oblique overview of the whole tileset; range 0 lets CesiumJS fit the bounding sphere.
    await viewer.zoomTo(tileset, new Cesium.HeadingPitchRange(0, Cesium.Math.toRadians(-40), 0));
    citylod.ready = true;
    log('ready');
  }

  load().catch((err) => {
    citylod.error = String(err && err.message ? err.message : err);
    statusEl.textContent = `could not load ${tilesetUrl}: ${citylod.error}`;
    console.error('[citylod] tileset load failed:', citylod.error);
  });

  // --- landmark exaggeration ---------------------------------------------------------------------------------
  // The thesis' view-dependent landmark enhancement, done per vertex from the feature metadata the exporter writes
  // (exporter/export.py PROPERTIES; the rule of api.landmark_scale and lm.clearing_push): a landmark (lm_role 1)
  // is scaled uniformly about its footprint centre at ground level, so it grows wider and taller from its base;
  // a building its scaled footprint circle would cover (lm_role 2) moves away from that landmark by the overlap
  // the scaling adds. Both read the landmark's scale for the camera's distance to that centre, so the parts of a
  // landmark and its neighbours, in whatever tiles they are, agree on one scale. (api.landmark_exaggeration
  // measures to the middle of the landmark's height, which the metadata does not carry; the two distances differ
  // by at most half that height, so they pick different intervals only that close to a boundary.)
  // lm_centre_* are in metres in the mesh's frame (y up); positionMC is POSITION as stored, metres / the node's
  // scale for quantized (compact) geometry, so both are brought to positionMC's units; czm_modelView adds the
  // node's and the tile's transforms. Primitives without these properties (older tilesets) get no custom
  // vertex shader from CesiumJS (a console warning), so nothing moves. Bounding volumes are not enlarged: a scaled
  // landmark whose tile is culled is not drawn.
  const LANDMARK_VS = `
    void vertexMain(VertexInput vsInput, inout czm_modelVertexOutput vsOutput) {
      uint role = vsInput.metadata.lm_role;
      float scaleFrom = vsInput.metadata.lm_scale_from_m;
      float scaleStep = vsInput.metadata.lm_scale_step; // not 'step': that would hide the GLSL built-in
      float maxScale = vsInput.metadata.lm_max_scale;
      if (role == 0u || !(scaleFrom > 0.0 && scaleStep > 1.0 && maxScale > 1.0)) return;
      // positionMC is POSITION as stored: quantized (KHR_mesh_quantization) it is metres / step, the node's scale,
      // which czm_model carries (the tile transforms are rigid); the metadata is in metres in the mesh's frame
      float unit = length(czm_model[0].xyz);
      vec3 centre = vec3(vsInput.metadata.lm_centre_x, vsInput.metadata.lm_centre_y, vsInput.metadata.lm_centre_z)
        / unit;
      float d = length((czm_modelView * vec4(centre, 1.0)).xyz);
      if (d < scaleFrom) return;
      // interval i, from scaleFrom * scaleStep^i on, scales by min(scaleStep^(i + 1), maxScale)
      float s = min(pow(scaleStep, floor(log(d / scaleFrom) / log(scaleStep)) + 1.0), maxScale);
      if (role == 1u) {
        vsOutput.positionMC = centre + (vsOutput.positionMC - centre) * s;
      } else if (role == 2u) {
        float push = max(0.0, (s - 1.0) * vsInput.metadata.lm_radius_m - max(vsInput.metadata.lm_gap_m, 0.0));
        vsOutput.positionMC += push / unit * vec3(vsInput.metadata.lm_dir_x, vsInput.metadata.lm_dir_y,
          vsInput.metadata.lm_dir_z);
      }
    }`;
  let shader = null; // one instance: every tile shares its compiled programs

  function landmarkShader() {
    if (!shader) shader = new Cesium.CustomShader({ vertexShaderText: LANDMARK_VS });
    return shader;
  }

  const toggleEl = document.getElementById('exaggerate');

  // Property tables reach custom shaders through a texture fetch, which CesiumJS only does in WebGL 2;
  // in WebGL 1 the metadata fields would be missing and the shader would not compile, so it stays off.
  function setExaggeration(on) {
    on = Boolean(on);
    if (on && !scene.context.webgl2) {
      console.warn('[citylod] landmark exaggeration needs WebGL 2; left off');
      on = false;
    }
    citylod.exaggeration = on;
    toggleEl.checked = on;
    if (citylod.tileset) citylod.tileset.customShader = on ? landmarkShader() : undefined;
    log('landmark exaggeration', on ? 'on' : 'off');
    return on;
  }

  toggleEl.addEventListener('change', () => setExaggeration(toggleEl.checked));
  setExaggeration(new URLSearchParams(window.location.search).get('exaggerate') === '1');

  // --- status line -----------------------------------------------------------------------------------------
  // What the drawn tiles hold, by the exporter's `kind` property: a far tile's features are blocks (buildings
  // merged), so "features" alone would count a block of forty houses as one building; a block's n_members says
  // how many buildings it stands for, so the line can say how much of the city the view holds. Each content is
  // tallied once (WeakMap); tileVisible fires once per drawn tile per frame, so the frame's sums are final at
  // postRender.
  const KINDS = ['building', 'part', 'block'];
  const tallies = new WeakMap();
  const emptyTally = () => ({ building: 0, part: 0, block: 0, other: 0, members: 0 });
  let frameKinds = emptyTally();
  let shownKinds = { ...frameKinds };

  function tally(content) {
    let t = tallies.get(content);
    if (!t) {
      t = emptyTally();
      for (let i = 0; i < content.featuresLength; i++) {
        const feature = content.getFeature(i);
        const kind = feature.getProperty('kind');
        t[KINDS.includes(kind) ? kind : 'other'] += 1;
        if (kind === 'block') t.members += Number(feature.getProperty('n_members') || 0);
      }
      tallies.set(content, t);
    }
    return t;
  }

  scene.preRender.addEventListener(() => {
    frameKinds = emptyTally();
  });

  // Statistics are not public API in CesiumJS, hence the defensive reads.
  function stats() {
    const ts = citylod.tileset;
    const st = (ts && ts.statistics) || {};
    return {
      tilesLoaded: citylod.tileLoads,
      tilesWithContent: st.numberOfTilesWithContentReady || 0,
      triangles: st.numberOfTrianglesSelected || 0,
      features: st.numberOfFeaturesSelected || 0,
      // features of the drawn tiles by kind (building, part, block, other), and the buildings the blocks merge
      kinds: { building: shownKinds.building, part: shownKinds.part, block: shownKinds.block,
        other: shownKinds.other },
      blockMembers: shownKinds.members,
      pending: (st.numberOfPendingRequests || 0) + (st.numberOfTilesProcessing || 0),
      allTilesLoaded: citylod.allTilesLoaded,
      tileFailures: citylod.tileFailures,
    };
  }

  // "12,034 buildings shown: 379 on their own, 11,655 merged into 812 blocks": the buildings the view stands
  // for, then how they are drawn (a far view draws most of a city as blocks)
  function kindsText(k, members) {
    const fmt = (n) => n.toLocaleString('en');
    const parts = [`${fmt(k.building)} on their own`];
    if (k.part) parts.push(`${fmt(k.part)} building parts`);
    parts.push(`${fmt(members)} merged into ${fmt(k.block)} blocks`);
    if (k.other) parts.push(`${fmt(k.other)} other features`);
    return `${fmt(k.building + members)} buildings shown: ` + parts.join(', ');
  }

  let lastStatus = 0;
  scene.postRender.addEventListener(() => {
    shownKinds = frameKinds;
    const now = performance.now();
    if (!citylod.tileset || now - lastStatus < 500) return; // the DOM need not change every frame
    lastStatus = now;
    const s = stats();
    const fmt = (n) => n.toLocaleString('en');
    statusEl.textContent = `${fmt(s.tilesWithContent)} tiles loaded · ${fmt(s.triangles)} triangles · ` +
      kindsText(s.kinds, s.blockMembers) + (s.pending ? ` · loading ${s.pending}…` : '') +
      (s.tileFailures ? ` · ${s.tileFailures} failed` : '');
  });

  // --- picking ---------------------------------------------------------------------------------------------
  let selected = null;
  let selectedColor = null;

  // JSON-safe values: INT64 properties (osm ids) arrive as BigInt, which JSON and postMessage cannot carry.
  function featureProperties(feature) {
    const props = {};
    for (const id of feature.getPropertyIds()) {
      const v = feature.getProperty(id);
      props[id] = typeof v === 'bigint' ? v.toString() : v === undefined ? null : v;
    }
    return props;
  }

  function formatValue(v) {
    if (v === null || v === '') return null;
    if (typeof v === 'number' && !Number.isInteger(v)) return String(Math.round(v * 100) / 100);
    return String(v);
  }

  function showProperties(props) {
    propsEl.replaceChildren();
    titleEl.replaceChildren();
    hintEl.hidden = props !== null;
    if (props === null) {
      titleEl.textContent = 'No building selected';
      return;
    }
    // Title: the name, else "way 123"; it links to the object on openstreetmap.org.
    const link = document.createElement('a');
    link.href = `https://www.openstreetmap.org/${props.osm_type}/${props.osm_id}`;
    link.target = '_blank';
    link.rel = 'noopener';
    link.textContent = props.name || `${props.osm_type} ${props.osm_id}`;
    titleEl.append(link);
    for (const [id, v] of Object.entries(props)) {
      const row = propsEl.insertRow();
      const th = document.createElement('th');
      th.textContent = id;
      const td = document.createElement('td');
      const text = formatValue(v);
      if (text === null) {
        td.textContent = '—';
        td.className = 'empty';
      } else {
        if (/_colour$/.test(id) && /^#[0-9a-f]{6}$/i.test(text)) {
          const sw = document.createElement('span');
          sw.className = 'swatch';
          sw.style.background = text;
          td.append(sw);
        }
        td.append(text);
      }
      row.append(th, td);
    }
  }

  function select(feature) {
    if (selected) {
      // The tile may have been unloaded since; its feature is then gone and needs no reset.
      try {
        selected.color = selectedColor;
      } catch (e) {
        /* ignore */
      }
    }
    selected = feature;
    selectedColor = feature ? Cesium.Color.clone(feature.color) : null;
    if (feature) feature.color = HIGHLIGHT;
    citylod.lastPicked = feature ? featureProperties(feature) : null;
    showProperties(citylod.lastPicked);
    if (feature) log('picked', citylod.lastPicked.osm_type, citylod.lastPicked.osm_id);
  }

  const handler = new Cesium.ScreenSpaceEventHandler(scene.canvas);
  handler.setInputAction((click) => {
    const picked = scene.pick(click.position);
    select(picked instanceof Cesium.Cesium3DTileFeature ? picked : null);
    citylod.picks += 1;
  }, Cesium.ScreenSpaceEventType.LEFT_CLICK);

  // --- test/automation helper ------------------------------------------------------------------------------
  // Look straight down (pitch -90°) at lon/lat/height (degrees, metres above the ellipsoid) from `range`
  // metres, then resolve once the tileset has loaded everything the new view needs (or after timeoutMs).
  function lookAt(lon, lat, height = 0, range = 300, timeoutMs = 60000) {
    viewer.camera.setView({
      destination: Cesium.Cartesian3.fromDegrees(lon, lat, height + range),
      orientation: { heading: 0, pitch: -Cesium.Math.PI_OVER_TWO, roll: 0 },
    });
    citylod.allTilesLoaded = false;
    return window.citylodCommon.settle(scene, () => citylod.tileset, timeoutMs).then((r) => {
      citylod.allTilesLoaded = r.loaded;
      return r;
    });
  }
})();
