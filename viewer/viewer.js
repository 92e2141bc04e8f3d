// The rolamos viewer: OpenSeadragon over the store's Deep Zoom tiles, with the sidecars' patch
// outlines, frame footprints and trajectory, object detections, cursor coordinates (pixel and
// map) and full-resolution export of the view or of a drawn rectangle. Served by
// `rolamos serve`; `rolamos tiles` writes it with a static images.json (no export there).
(function () {
  'use strict';
  const statics = window.ROLAMOS_STATIC === true;
  const $ = (id) => document.getElementById(id);
  const state = { images: [], current: null, overlays: null, svg: null, drawing: false };
  window.rolamos = state;  // for the browser tests and for curious users

  const viewer = OpenSeadragon({
    id: 'map',
    showNavigationControl: false,
    showNavigator: true,
    maxTilesPerFrame: 16,  // OpenSeadragon starts 1 tile load per frame by default: a jump to a new area took ~0.7 s
    maxZoomPixelRatio: 4,
    visibilityRatio: 0.5,
    crossOriginPolicy: 'Anonymous',
    drawer: 'canvas',  // a 2-D canvas: pixels can be read back (tests, screenshots) on any GPU
    imageSmoothingEnabled: true,
  });
  state.viewer = viewer;

  function status(text) { $('status').textContent = text; }

  async function json(url) {
    const r = await fetch(url);
    if (!r.ok) throw new Error(url + ': HTTP ' + r.status);
    return r.json();
  }

  async function loadImages() {
    if (statics) {
      // images.json of `rolamos tiles`: Deep Zoom descriptors, or XYZ directories described here.
      state.images = (await json('images.json')).map((i) => ({ name: i.name, width: i.width, height: i.height,
        dzi: i.format === 'dzi' ? i.url : {
          width: i.width, height: i.height, tileSize: i.tile_size, tileOverlap: 0,
          minLevel: i.dzi_level_of_zoom_0, maxLevel: i.dzi_level_of_zoom_0 + i.max_zoom,
          getTileUrl: (level, x, y) => i.url.replace('{z}', level - i.dzi_level_of_zoom_0).replace('{x}', x).replace('{y}', y),
        },
        overlays: 'overlays/' + i.name + '.json' }));
    } else {
      state.images = (await json('api/images')).map((i) => ({ name: i.name, width: i.width, height: i.height,
                                                             dzi: i.dzi.replace(/^\//, ''),
                                                             overlays: 'api/overlays/' + i.name }));
    }
    addOptions(state.images);
    // The map page, when an image is on Earth (its Web Mercator tiles).
    try {
      const listed = statics ? await json('images.json') : await json('api/images');
      $('map-link').hidden = !listed.some((i) => i.webmercator);
    } catch (e) { /* no map page then */ }
    if (!state.images.length) { status('the store has no images yet'); return; }
    const wanted = new URLSearchParams(location.search).get('image');
    open(state.images.find((i) => i.name === wanted) || state.images[0]);
  }

  function addOptions(images) {
    const select = $('image');
    for (const i of images) {
      const o = document.createElement('option');
      o.value = i.name;
      o.textContent = i.name + ' (' + i.width + ' x ' + i.height + ')';
      select.appendChild(o);
    }
  }

  // A store being written (mosaic --live): every second the run's status, new patches added to the
  // list as they are written and, when following, the live view: the open patch as it grows (the
  // engine's preview), the patches it continues beneath it, the track and the current frame.
  state.live = null;
  async function pollLive() {
    let st;
    try { st = await json('api/status'); } catch (e) { return; }
    if (!st.running && !state.live) return;  // a finished store: nothing to follow
    state.live = st;
    $('follow-label').hidden = false;
    const age = st.last_frame_time ? Math.max(0, Date.now() / 1000 - st.last_frame_time) : null;
    $('live').textContent = (st.running ? 'live: ' : 'live run ended: ') + st.frames_received + ' frames, ' +
      st.frames_registered + ' registered, ' + st.frames_rejected + ' rejected, ' + st.frames_skipped + ' skipped' +
      (st.coverage_lost ? ' (coverage lost ' + st.coverage_lost + ')' : '') + ', ' +
      st.patches + ' patches' + (st.open_patch ? ', patch ' + st.open_patch + ' open' : '') +
      (st.latency_ms_p50 ? ', latency ' + Math.round(st.latency_ms_p50) + ' ms' : '') +
      (st.running && st.shedding ? ', behind: fewer keyframes described' : '') +
      (age !== null && st.running ? ', last frame ' + age.toFixed(1) + ' s ago' : '') + ' \u00a0 ';
    if (st.images_served !== state.images.length) {
      const listed = new Set(state.images.map((i) => i.name));
      const all = await json('api/images');
      const fresh = all.filter((i) => !listed.has(i.name)).map((i) => ({
        name: i.name, width: i.width, height: i.height, dzi: i.dzi.replace(/^\//, ''), overlays: 'api/overlays/' + i.name }));
      // The preview comes and goes with the open patch.
      const gone = state.images.filter((i) => i.name === 'live' && !all.some((a) => a.name === 'live'));
      if (gone.length) { state.images = state.images.filter((i) => i.name !== 'live'); $('image').querySelector('option[value="live"]')?.remove(); }
      state.images.push(...fresh);
      addOptions(fresh);
    }
    const following = $('follow').checked;
    if (st.running && (following || (state.current && state.current.name === 'live'))) {
      await showLive();
      return;
    }
    const patches = state.images.filter((i) => i.name.startsWith('patch'))
      .sort((a, b) => parseInt(a.name.slice(6), 10) - parseInt(b.name.slice(6), 10));
    if ((!state.current || (following && state.current.name === 'live')) && patches.length) open(patches[patches.length - 1]);
  }

  // The live view: one world in the open patch's coordinates. Each image is placed by the
  // similarity nearest its homography at its centre (OpenSeadragon places images by position,
  // width and rotation); tiles keep their alpha (webp) so layers show through where empty.
  function similarity(H, w, h) {
    const map = (x, y) => { const z = H[6] * x + H[7] * y + H[8];
      return [(H[0] * x + H[1] * y + H[2]) / z, (H[3] * x + H[4] * y + H[5]) / z]; };
    const c = map(w / 2, h / 2), e = map(w / 2 + 1, h / 2);
    const s = Math.hypot(e[0] - c[0], e[1] - c[1]);
    return { x: c[0] - s * w / 2, y: c[1] - s * h / 2, width: s * w,
             degrees: Math.atan2(e[1] - c[1], e[0] - c[0]) * 180 / Math.PI };
  }
  // Resolves with the layer, or null when it cannot be added: the tile source failed, the user
  // opened another image (OpenSeadragon then drops the images it was adding without a word), or
  // it did not come within LAYER_TIMEOUT_MS. A page waiting on a layer that never comes would
  // stop following the run. A layer that comes after that is taken out again; the next poll
  // adds what is still missing.
  const LAYER_TIMEOUT_MS = 10000;
  const layersComing = new Set();  // each layer being added: its settle function
  function addLayer(image, index) {
    return new Promise((resolve) => {
      let settled = false;
      const settle = (item) => {
        if (settled) return false;
        settled = true;
        clearTimeout(timer);
        layersComing.delete(settle);
        resolve(item);
        return true;
      };
      const timer = setTimeout(() => settle(null), LAYER_TIMEOUT_MS);
      layersComing.add(settle);
      const p = similarity(image.to_world, image.width, image.height);
      viewer.addTiledImage({ tileSource: image.dzi.replace(/^\//, '') + '?format=webp', x: p.x, y: p.y, width: p.width,
        index,
        success: (e) => {
          if (settled) { viewer.world.removeItem(e.item); return; }
          e.item.setRotation(p.degrees, true);
          settle(e.item);
        },
        error: () => settle(null) });
    });
  }
  // Settles once the image OpenSeadragon was last asked to open has opened (or failed to).
  let opening = Promise.resolve();
  function whenOpened() {
    return new Promise((resolve) => {
      const done = () => { viewer.removeHandler('open', done); viewer.removeHandler('open-failed', done); resolve(); };
      viewer.addHandler('open', done);
      viewer.addHandler('open-failed', done);
    });
  }
  const wait = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
  function abandonLayers() { for (const settle of [...layersComing]) settle(null); }
  // One update of the live view at a time: the poll and a user choosing "live" in the list would
  // otherwise build two worlds at once, each over the other's layers. A call while one runs
  // waits for it and asks for one more after it, which nobody waits for: the poll (and so the
  // status line) is held up by one update at most, however often the user chooses.
  let liveRunning = null, liveAgain = false;
  function showLive() {
    if (liveRunning) { liveAgain = true; return liveRunning; }
    liveRunning = updateLive().finally(() => {
      liveRunning = null;
      if (liveAgain) { liveAgain = false; showLive(); }
    });
    return liveRunning;
  }
  async function updateLive() {
    let view;
    try { view = await json('api/live'); } catch (e) { return; }
    if (!view.preview) return;  // nothing open yet (or the run is closing its patch)
    let lv = state.liveView;
    const key = view.patch + ':' + view.patches.map((p) => p.patch).join(',');
    if (!lv || state.current !== lv.image || lv.key !== key) {
      // A new open patch: a new world, once an image being opened has come (else OpenSeadragon
      // would add it into this world later, and move the view to it).
      const was = state.current;
      await Promise.race([opening, wait(LAYER_TIMEOUT_MS)]);
      if (state.current !== was) return;  // the user chose another image meanwhile
      const image = { name: 'live', width: view.preview.width, height: view.preview.height, live: true };
      state.current = image;
      state.overlays = null;
      $('image').value = 'live';
      viewer.world.removeAll();
      if (state.svg) { viewer.removeOverlay(state.svg); state.svg = null; }
      lv = state.liveView = { image, key, preview: null, version: null, missing: [] };
      lv.preview = await addLayer(view.preview, 0);
      lv.version = lv.preview ? view.preview.version : null;
      lv.missing = view.patches.slice().reverse();
      viewer.viewport.fitBounds(worldBounds(view), true);
    } else if (lv.version !== view.preview.version) {
      // The same patch grown: the new preview goes in beneath, the old one leaves once it shows.
      const old = lv.preview;
      const item = await addLayer(view.preview, 0);
      if (item && state.liveView === lv) {
        lv.preview = item;
        lv.version = view.preview.version;
        const drop = () => { if (old) viewer.world.removeItem(old); };
        if (item.getFullyLoaded()) drop(); else item.addOnceHandler('fully-loaded-change', drop);
      } else if (item) {
        viewer.world.removeItem(item);
      }
    }
    await addClosedPatches(lv);
    if (state.liveView !== lv) return;  // the user chose another image meanwhile
    lv.view = view;
    drawLive(view);
    const g = view.georef;
    $('live').textContent += g ? 'georeferenced by ' + g.frames + ' fixes (' + g.crs + ', residual ' +
      g.residual_median_m.toFixed(2) + ' m) \u00a0 ' : (view.navigation ? 'navigation: waiting for fixes \u00a0 ' : '');
    if (view.navigation && view.navigation.lines_skipped)
      $('live').textContent += view.navigation.lines_skipped + ' navigation lines skipped \u00a0 ';
    if ($('follow').checked && view.footprint.length) {
      const c = view.footprint.reduce((a, p) => [a[0] + p[0] / 4, a[1] + p[1] / 4], [0, 0]);
      viewer.viewport.panTo(new OpenSeadragon.Point(c[0], c[1]));
    }
    state.ready = true;
    status('live: patch ' + view.patch + ' open, ' + view.patches.length + ' closed beneath it');
  }
  // The closed patches beneath the live view `lv`, oldest first; one the server could not give
  // yet (its tiles still being written) is tried again at the next poll.
  async function addClosedPatches(lv) {
    const still = [];
    for (const p of lv.missing) {
      if (state.liveView !== lv) return;
      const item = await addLayer({ ...p, dzi: 'dzi/' + p.name + '.dzi' });
      if (!item) still.push(p);
      else if (state.liveView !== lv) viewer.world.removeItem(item);
    }
    lv.missing = still;
  }
  function worldBounds(view) {
    const pts = view.track.concat(view.footprint);
    const m = view.preview.to_world, w = view.preview.width, h = view.preview.height;
    for (const [x, y] of [[0, 0], [w, 0], [w, h], [0, h]]) {
      const z = m[6] * x + m[7] * y + m[8];
      pts.push([(m[0] * x + m[1] * y + m[2]) / z, (m[3] * x + m[4] * y + m[5]) / z]);
    }
    const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
    const x0 = Math.min(...xs), y0 = Math.min(...ys);
    return new OpenSeadragon.Rect(x0, y0, Math.max(1, Math.max(...xs) - x0), Math.max(1, Math.max(...ys) - y0));
  }
  // The track and the current frame's footprint, in world coordinates.
  function drawLive(view) {
    if (state.svg) viewer.removeOverlay(state.svg);
    const b = worldBounds(view);
    const svg = document.createElementNS(SVG, 'svg');
    svg.setAttribute('class', 'overlay');
    svg.setAttribute('viewBox', [b.x, b.y, b.width, b.height].join(' '));
    svg.setAttribute('preserveAspectRatio', 'none');
    const pts = (list) => list.map((p) => p[0] + ',' + p[1]).join(' ');
    const add = (tag, cls, attrs) => {
      const e = document.createElementNS(SVG, tag);
      e.setAttribute('class', cls);
      for (const k in attrs) e.setAttribute(k, attrs[k]);
      svg.appendChild(e);
    };
    if ($('show-trajectory').checked && view.track.length > 1) add('polyline', 'trajectory', { points: pts(view.track) });
    if (view.footprint.length === 4) add('polygon', 'current-frame', { points: pts(view.footprint) });
    viewer.addOverlay({ element: svg, location: b });
    state.svg = svg;
  }

  function open(image) {
    // Not ready until this image's overlays are drawn (the previous image's readiness would
    // otherwise stand while they load).
    state.ready = false;
    if (image.name === 'live') {
      $('follow').checked = true;
      if (!(state.current && state.current.live)) state.liveView = null;  // back from another image: a new view
      showLive();
      return;
    }
    state.liveView = null;
    abandonLayers();
    state.current = image;
    state.overlays = null;
    $('image').value = image.name;
    state.tilesLoaded = 0;
    opening = whenOpened();
    viewer.open(image.dzi);
    status('opening ' + image.name);
  }

  viewer.addHandler('open', async () => {
    const image = state.current;
    if (!image || image.live) return;
    status(image.name + ': ' + image.width + ' x ' + image.height + ' px');
    try {
      state.overlays = await json(image.overlays);
    } catch (e) {
      state.overlays = null;
      status(image.name + ': no overlays (' + e.message + ')');
    }
    objectControls(state.overlays);
    drawOverlays();
    state.ready = true;
  });
  // The class list and score range of this image's detections; the density switch when it has a layer.
  function objectControls(o) {
    const detections = (o && o.detections) || [];
    $('object-filters').hidden = detections.length === 0;
    $('density-label').hidden = !(o && o.density);
    const select = $('object-class'), chosen = select.value;
    const classes = [...new Set(detections.map((d) => d.class))].sort();
    select.innerHTML = '<option value="">all classes</option>' + classes.map((c) => '<option>' + c + '</option>').join('');
    if (classes.includes(chosen)) select.value = chosen;
    if (detections.length) {
      const range = $('object-score');
      range.min = Math.floor(Math.min(...detections.map((d) => d.score)) * 10) / 10;
      range.max = Math.ceil(Math.max(...detections.map((d) => d.score)) * 10) / 10;
      if (parseFloat(range.value) < parseFloat(range.min)) range.value = range.min;
      $('object-score-value').textContent = parseFloat(range.value).toFixed(2);
    }
  }
  function redraw() { if (state.current && state.current.live && state.liveView && state.liveView.view) drawLive(state.liveView.view); else drawOverlays(); }
  viewer.addHandler('tile-loaded', () => { state.tilesLoaded = (state.tilesLoaded || 0) + 1; });
  viewer.addHandler('open-failed', (e) => status('cannot open ' + state.current.name + ': ' + e.message));

  // One SVG over the whole image, in image pixels (viewBox), so shapes zoom with the map.
  const SVG = 'http://www.w3.org/2000/svg';
  function drawOverlays() {
    if (state.svg) viewer.removeOverlay(state.svg);
    state.svg = null;
    const o = state.overlays, image = state.current;
    if (!o) return;
    const svg = document.createElementNS(SVG, 'svg');
    svg.setAttribute('class', 'overlay');
    svg.setAttribute('viewBox', '0 0 ' + image.width + ' ' + image.height);
    svg.setAttribute('preserveAspectRatio', 'none');
    const add = (tag, cls, attrs) => {
      const e = document.createElementNS(SVG, tag);
      e.setAttribute('class', cls);
      for (const k in attrs) e.setAttribute(k, attrs[k]);
      svg.appendChild(e);
      return e;
    };
    const pts = (list) => list.map((p) => p[0] + ',' + p[1]).join(' ');
    if ($('show-outlines').checked) for (const p of o.outlines) add('polygon', 'outline', { points: pts(p.points) });
    if ($('show-footprints').checked) for (const f of o.footprints) add('polygon', 'footprint', { points: pts(f.points) });
    // The confidence layer: every frame's footprint filled by how sure the aligned map is of it
    // (rolamos align's uncertainty_px): green up to 0.5 px, through yellow to red at 5 px and more,
    // hatched red where the frame sits far off its own edges.
    if ($('show-confidence').checked) {
      for (const f of o.footprints) {
        if (f.uncertainty_px === undefined) continue;
        const t = Math.min(1, Math.max(0, Math.log10(Math.max(f.uncertainty_px, 0.5) / 0.5)));  // 0.5 px -> 0, 5 px -> 1
        const hue = Math.round(120 * (1 - t));
        const e = add('polygon', f.doubtful ? 'confidence doubtful' : 'confidence', { points: pts(f.points) });
        e.style.fill = 'hsl(' + hue + ', 90%, 50%)';
        const title = document.createElementNS(SVG, 'title');
        title.textContent = 'frame ' + f.frame + ': uncertainty ' + f.uncertainty_px.toFixed(2) + ' px, residual ' +
          (f.residual_px || 0).toFixed(2) + ' px' + (f.doubtful ? ' (far off its own edges)' : '');
        e.appendChild(title);
      }
    }
    if ($('show-trajectory').checked && o.trajectory.length > 1)
      add('polyline', 'trajectory', { points: pts(o.trajectory.map((t) => t.point)) });
    // The density layer: each cell filled by its objects per unit area, transparent at none,
    // through orange to red at the map's highest.
    if ($('show-density').checked && o.density) {
      const top = Math.max(1e-9, ...o.density.cells.map((c) => c.density));
      for (const c of o.density.cells) {
        const e = add('rect', 'density', { x: c.bbox[0], y: c.bbox[1], width: c.bbox[2], height: c.bbox[3] });
        const t = c.density / top;
        e.style.fill = 'hsla(' + Math.round(40 * (1 - t)) + ', 95%, 50%, ' + (0.15 + 0.5 * t).toFixed(2) + ')';
        const title = document.createElementNS(SVG, 'title');
        title.textContent = c.count + ' objects, ' + c.density.toPrecision(3) + ' ' + o.density.unit;
        e.appendChild(title);
      }
    }
    if ($('show-detections').checked) {
      const cls = $('object-class').value, min = parseFloat($('object-score').value);
      for (const d of o.detections) {
        if ((cls && d.class !== cls) || d.score < min) continue;
        add('rect', 'detection', { x: d.bbox[0], y: d.bbox[1], width: d.bbox[2], height: d.bbox[3] });
        const t = add('text', 'detection-label', { x: d.bbox[0], y: d.bbox[1] - 4 });
        t.textContent = d.class + ' ' + d.score.toFixed(2);
      }
    }
    const aspect = image.height / image.width;
    viewer.addOverlay({ element: svg, location: new OpenSeadragon.Rect(0, 0, 1, aspect) });
    state.svg = svg;
  }
  for (const id of ['show-outlines', 'show-footprints', 'show-confidence', 'show-trajectory', 'show-detections',
                    'show-density', 'object-class'])
    $(id).addEventListener('change', redraw);
  $('object-score').addEventListener('input', () => {
    $('object-score-value').textContent = parseFloat($('object-score').value).toFixed(2);
    redraw();
  });
  $('image').addEventListener('change', (e) => {
    if (e.target.value !== 'live') $('follow').checked = false;  // the user looks elsewhere
    open(state.images.find((i) => i.name === e.target.value));
  });
  $('home').addEventListener('click', () => viewer.viewport.goHome());
  $('full').addEventListener('click', () => viewer.viewport.zoomTo(viewer.viewport.imageToViewportZoom(1.0)));

  // Cursor: image pixel, and map coordinates through the georeference when there is one.
  new OpenSeadragon.MouseTracker({
    element: viewer.element,
    moveHandler: (e) => {
      if (!state.current || !viewer.world.getItemCount()) return;
      const live = state.current.live && state.liveView && state.liveView.view;
      // The live view's world is viewport coordinates (open patch pixels); images are not.
      const p = live ? viewer.viewport.pointFromPixel(e.position) : viewer.viewport.viewerElementToImageCoordinates(e.position);
      let text = 'x ' + p.x.toFixed(1) + '  y ' + p.y.toFixed(1) + ' px';
      const g = live ? state.liveView.view.georef : state.overlays && state.overlays.georef;
      if (g) {
        const t = g.geotransform;
        const mx = t[0] + p.x * t[1] + p.y * t[2], my = t[3] + p.x * t[4] + p.y * t[5];
        text += '   ' + g.crs + '  E ' + mx.toFixed(3) + '  N ' + my.toFixed(3);
      }
      $('cursor').textContent = text;
    },
  });

  // Export at full resolution through the server's export code.
  function exportUrl(x, y, w, h) {
    const c = state.current;
    x = Math.max(0, Math.floor(x)); y = Math.max(0, Math.floor(y));
    w = Math.min(c.width - x, Math.ceil(w)); h = Math.min(c.height - y, Math.ceil(h));
    if (w <= 0 || h <= 0) return null;
    return 'api/export/' + c.name + '?region=' + [x, y, w, h].join(',') + '&format=' + $('export-format').value;
  }
  state.exportUrl = exportUrl;
  function download(url) {
    if (!url) { status('nothing of the image is in that area'); return; }
    const a = document.createElement('a');
    a.href = url;
    a.download = '';
    document.body.appendChild(a);
    a.click();
    a.remove();
    status('exporting ' + url);
  }
  function viewRegion() {
    const b = viewer.viewport.viewportToImageRectangle(viewer.viewport.getBounds(true));
    return [b.x, b.y, b.width, b.height];
  }
  state.viewRegion = viewRegion;
  if (statics) {
    document.querySelector('header .export').style.display = 'none';
  } else {
    $('export-view').addEventListener('click', () => download(exportUrl(...viewRegion())));
    // Rectangle: press the button, then drag on the map (panning is off meanwhile).
    let start = null, box = null;
    $('draw').addEventListener('click', () => {
      state.drawing = !state.drawing;
      $('draw').classList.toggle('active', state.drawing);
      viewer.setMouseNavEnabled(!state.drawing);
    });
    new OpenSeadragon.MouseTracker({
      element: viewer.element,
      pressHandler: (e) => {
        if (!state.drawing) return;
        start = viewer.viewport.viewerElementToImageCoordinates(e.position);
        box = document.createElement('div');
        box.className = 'selection';
        viewer.addOverlay(box, viewer.viewport.imageToViewportRectangle(start.x, start.y, 0, 0));
      },
      dragHandler: (e) => {
        if (!state.drawing || !start) return;
        const p = viewer.viewport.viewerElementToImageCoordinates(e.position);
        viewer.updateOverlay(box, viewer.viewport.imageToViewportRectangle(
          Math.min(start.x, p.x), Math.min(start.y, p.y), Math.abs(p.x - start.x), Math.abs(p.y - start.y)));
      },
      releaseHandler: (e) => {
        if (!state.drawing || !start) return;
        const p = viewer.viewport.viewerElementToImageCoordinates(e.position);
        viewer.removeOverlay(box);
        download(exportUrl(Math.min(start.x, p.x), Math.min(start.y, p.y), Math.abs(p.x - start.x), Math.abs(p.y - start.y)));
        start = null;
        $('draw').click();
      },
    });
  }
  loadImages().catch((e) => status(e.message));
  if (!statics) {
    // Once a second: a frame's footprint reaches the page within about 1.5 s of its arrival.
    let polling = false;
    const poll = async () => { if (polling) return; polling = true; try { await pollLive(); } finally { polling = false; } };
    poll();
    setInterval(poll, 1000);
  }
})();
