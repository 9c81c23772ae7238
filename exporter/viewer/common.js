// Shared by the viewer (viewer.js) and the roof gallery (gallery.js): an offline CesiumJS viewer on a plain
// globe (no ion, no imagery), its render errors reported to the page's hooks, and the tileset URL.
/* global Cesium */
(() => {
  'use strict';

  // hooks: the page's window object for tests (gets .viewer and .error); tag: the console prefix.
  function makeViewer(containerId, hooks, tag) {
    Cesium.Ion.defaultAccessToken = ''; // no ion: an empty token stops CesiumJS from asking ion for anything
    const viewer = new Cesium.Viewer(containerId, {
      baseLayer: false, // no imagery: a plain globe coloured below
      baseLayerPicker: false,
      geocoder: false,
      homeButton: false,
      sceneModePicker: false,
      navigationHelpButton: false,
      animation: false,
      timeline: false,
      fullscreenButton: false,
      infoBox: false, // the pages' own panels show properties
      selectionIndicator: false,
      skyBox: false,
      skyAtmosphere: false,
      shadows: false,
      // Lets screenshots (and readPixels/toDataURL) read the last frame.
      contextOptions: { webgl: { preserveDrawingBuffer: true } },
    });
    hooks.viewer = viewer;
    const scene = viewer.scene;
    scene.globe.baseColor = Cesium.Color.fromCssColorString('#5b6670');
    scene.globe.showGroundAtmosphere = false; // keep the ground a flat, predictable colour
    scene.backgroundColor = Cesium.Color.fromCssColorString('#1d2329');
    viewer.clock.shouldAnimate = false;
    scene.renderError.addEventListener((_scene, err) => {
      hooks.error = String(err);
      console.error(`${tag} render error:`, err);
    });
    return viewer;
  }

  // ?tileset=URL, else the tileset the server serves.
  function tilesetUrl() {
    return new URLSearchParams(window.location.search).get('tileset') || '/tiles/tileset.json';
  }

  // Resolve once the tileset has loaded everything the current view needs (or after timeoutMs). allTilesLoaded
  // only fires when loading actually happened, so this polls tileset.tilesLoaded, after a few frames so the
  // traversal from the current camera has issued its requests. tileset: a function, as it may load later.
  function settle(scene, tileset, timeoutMs = 60000) {
    const t0 = performance.now();
    return new Promise((resolve) => {
      let frames = 0;
      const remove = scene.postRender.addEventListener(() => {
        frames += 1;
        const loaded = frames >= 3 && tileset() && tileset().tilesLoaded;
        if (!loaded && performance.now() - t0 < timeoutMs) return;
        remove();
        resolve({ loaded: Boolean(loaded), ms: Math.round(performance.now() - t0), frames });
      });
    });
  }

  // Resolve after n rendered frames.
  function frames(scene, n) {
    return new Promise((resolve) => {
      let k = 0;
      const remove = scene.postRender.addEventListener(() => {
        if (++k >= n) { remove(); resolve(); }
      });
    });
  }

  // Place the camera (cam: lon, lat, height above the ellipsoid in metres, heading, pitch, fovDeg: CesiumJS's
  // field of view, the wider side's), wait until the view's tiles loaded, call beforeTrim() (what the session
  // holds on arrival), unload every tile the view does not need (trimLoadedTiles, so the statistics are the
  // view's alone) and wait again: {loaded, ms, tileFailures} of this view. The benchmark drivers' common step.
  async function viewCamera(viewer, tileset, cam, timeoutMs, beforeTrim = () => {}) {
    const scene = viewer.scene;
    const R = Cesium.Math.toRadians;
    viewer.camera.frustum.fov = R(cam.fovDeg);
    viewer.camera.setView({
      destination: Cesium.Cartesian3.fromDegrees(cam.lon, cam.lat, cam.height),
      orientation: { heading: R(cam.heading), pitch: R(cam.pitch), roll: 0 },
    });
    const failuresBefore = window.citylod.tileFailures;
    const first = await settle(scene, () => tileset, timeoutMs);
    beforeTrim();
    tileset.trimLoadedTiles();
    await frames(scene, 3);
    const settled = await settle(scene, () => tileset, timeoutMs);
    return { loaded: first.loaded && settled.loaded, ms: first.ms + settled.ms,
      tileFailures: window.citylod.tileFailures - failuresBefore };
  }

  window.citylodCommon = { makeViewer, tilesetUrl, settle, frames, viewCamera };
})();
