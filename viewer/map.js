// The georeferenced images of a store on Earth: their Web Mercator tiles (`rolamos serve`,
// /tiles/NAME/webmercator/{z}/{x}/{y}.png) in Leaflet, over the base map the server was given
// (`rolamos serve --basemap URL`); none is fetched unless one was configured.
(function () {
  'use strict';
  const $ = (id) => document.getElementById(id);
  const state = { layers: {}, basemap: null };
  window.rolamosMap = state;  // for the browser tests

  async function json(url) {
    const r = await fetch(url);
    if (!r.ok) throw new Error(url + ': HTTP ' + r.status);
    return r.json();
  }

  async function start() {
    // `rolamos tiles` writes images.json (the tiles beside it, no base map); the server, its API.
    const statics = window.ROLAMOS_STATIC === true;
    const [config, images] = statics
      ? [{}, (await json('images.json')).map((i) => Object.assign({}, i, i.webmercator ? {
          webmercator: Object.assign({}, i.webmercator, { tiles: i.webmercator.url }) } : {}))]
      : await Promise.all([json('api/config'), json('api/images')]);
    const onEarth = images.filter((i) => i.webmercator);
    const map = L.map('map', { zoomControl: true, attributionControl: true, maxZoom: 30 });
    state.map = map;
    const overlays = {};
    if (config.basemap) {
      state.basemap = L.tileLayer(config.basemap, { maxZoom: 30, maxNativeZoom: config.basemap_max_zoom || 19,
                                                    attribution: config.basemap_attribution || '' }).addTo(map);
    }
    let bounds = null;
    for (const i of onEarth) {
      const m = i.webmercator;
      const b = L.latLngBounds([m.bounds[1], m.bounds[0]], [m.bounds[3], m.bounds[2]]);
      const layer = L.tileLayer(m.tiles.replace(/^\//, ''), { minZoom: 0, maxZoom: 30, maxNativeZoom: m.max_zoom,
                                                             bounds: b, tileSize: 256 });
      state.layers[i.name] = layer;
      overlays[i.name] = layer;
      if (i.name === 'mosaic' || !bounds) bounds = b;
    }
    if (!onEarth.length) {
      $('status').textContent = 'no image of this store is georeferenced (compose --navigation places it on Earth)';
      map.setView([0, 0], 2);
      return;
    }
    (state.layers.mosaic || Object.values(state.layers)[0]).addTo(map);
    L.control.layers(state.basemap ? { 'base map': state.basemap } : {}, overlays).addTo(map);
    map.fitBounds(bounds);
    map.on('mousemove', (e) => {
      $('cursor').textContent = e.latlng.lat.toFixed(7) + ', ' + e.latlng.lng.toFixed(7);
    });
    $('status').textContent = config.basemap ? '' : 'no base map (rolamos serve --basemap URL adds one)';
    state.ready = true;
  }
  start().catch((e) => { $('status').textContent = e.message; });
})();
