// Leaflet (the web map library most sites use) in Debian's Chromium, showing the XYZ tiles of
// `rolamos serve` as any web map would: a plain L.tileLayer over L.CRS.Simple at full resolution,
// the view on the mosaic's bottom-right corner where the edge tiles are. The screenshot must equal
// `rolamos export` of the same pixels inside the image, right up to its last column and row (a
// partial edge tile would be stretched to 256 pixels), and show the page's own background past
// it (the tiles' transparent part). Exits 77 (ctest: skipped) without Chromium or playwright-core.
//   node tests/viewer/leaflet_e2e.mjs ROLAMOS_CLI SCRATCH_DIR ARTEFACTS_DIR
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';

import { check, chromiumOrSkip, finish, launch, requireViewer, serve } from './support.mjs';

const [cli, scratch, artefacts] = process.argv.slice(2);
const chromium = chromiumOrSkip();
const leafletDir = path.join(path.dirname(requireViewer.resolve('leaflet/package.json')), 'dist');
const run = (...args) => execFileSync(cli, args, { cwd: scratch, encoding: 'utf8' });

fs.rmSync(scratch, { recursive: true, force: true });
fs.mkdirSync(scratch, { recursive: true });
fs.mkdirSync(artefacts, { recursive: true });
run('synth', '-q', '-o', 'survey', '--frames', '24', '--width', '480', '--height', '360', '--focal', '420');
run('mosaic', '-q', 'survey/frames', '-o', 's.rolamos');
run('compose', '-q', 's.rolamos', '--compression', 'zstd');

const { server, base } = await serve(cli, 's.rolamos', scratch);
const getBytes = (url) => new Promise((resolve, reject) => {
  http.get(url, (res) => {
    const chunks = [];
    res.on('data', (c) => chunks.push(c));
    res.on('end', () => resolve({ status: res.statusCode, body: Buffer.concat(chunks) }));
  }).on('error', reject);
});
const images = JSON.parse((await getBytes(base + '/api/images')).body.toString());
const mosaic = images.find((i) => i.name === 'mosaic');
const W = mosaic.width, H = mosaic.height, zmax = mosaic.xyz_max_zoom;
console.log(`mosaic ${W} x ${H}, zoom 0..${zmax}, served at ${base}`);

// The web map page, as a site would write it, from a server of its own (another origin).
const page = `<!doctype html><html><head><link rel="stylesheet" href="/leaflet.css">
<style>html,body,#map{margin:0;width:100%;height:100%;background:rgb(255,0,255)}</style></head>
<body><div id="map"></div><script src="/leaflet.js"></script><script>
const map = L.map('map', {crs: L.CRS.Simple, zoomControl: false, attributionControl: false,
                          fadeAnimation: false, zoomAnimation: false, markerZoomAnimation: false});
const bounds = L.latLngBounds(map.unproject([0, ${H}], ${zmax}), map.unproject([${W}, 0], ${zmax}));
const layer = L.tileLayer('${base}/tiles/mosaic/{z}/{x}/{y}.png',
                          {tileSize: 256, maxZoom: ${zmax}, minZoom: 0, noWrap: true, bounds: bounds});
window.loaded = new Promise((r) => layer.on('load', r));
layer.addTo(map);
// Full resolution (one image pixel a screen pixel), the image's bottom-right corner at most
// 700 px right of and 500 px below the view's top-left corner (the edge tiles in view).
const size = map.getSize();
const centre = [Math.max(0, ${W} - 700) + size.x / 2, Math.max(0, ${H} - 500) + size.y / 2];
map.setView(map.unproject(centre, ${zmax}), ${zmax});
window.topLeft = () => { const p = map.project(map.containerPointToLatLng([0, 0]), ${zmax}); return [p.x, p.y]; };
</script></body></html>`;
const site = http.createServer((req, res) => {
  if (req.url === '/') return res.end(page);
  const file = path.join(leafletDir, path.basename(req.url));
  if (!fs.existsSync(file)) { res.statusCode = 404; return res.end(); }
  res.setHeader('Content-Type', file.endsWith('.css') ? 'text/css' : 'application/javascript');
  res.end(fs.readFileSync(file));
}).listen(0, '127.0.0.1');
await new Promise((r) => site.on('listening', r));
const siteUrl = `http://127.0.0.1:${site.address().port}/`;

const browser = await launch(chromium);
try {
  const context = await browser.newContext({ viewport: { width: 1000, height: 700 } });
  const tab = await context.newPage();
  const tileErrors = [];
  tab.on('response', (r) => { if (r.url().includes('/tiles/') && r.status() !== 200) tileErrors.push(r.status() + ' ' + r.url()); });
  await tab.goto(siteUrl);
  await tab.evaluate(() => window.loaded);
  await tab.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
  check(tileErrors.length === 0, 'every tile Leaflet asked for was served (' + tileErrors.slice(0, 3).join('; ') + ')');
  const [x0, y0] = (await tab.evaluate(() => window.topLeft())).map(Math.round);
  const shot = await tab.screenshot({ path: path.join(artefacts, 'leaflet-edge.png') });
  // The same pixels from the store, through the server's export (what rolamos export writes).
  const w = W - x0, h = H - y0;
  const exported = await getBytes(`${base}/api/export/mosaic?region=${x0},${y0},${w},${h}&format=png`);
  check(exported.status === 200, `export of ${x0},${y0},${w},${h}`);
  const result = await tab.evaluate(async ({ shot, exported, w, h }) => {
    const load = async (b64) => { const i = new Image(); i.src = 'data:image/png;base64,' + b64; await i.decode(); return i; };
    const [s, e] = await Promise.all([load(shot), load(exported)]);
    const pixels = (img, cw, ch) => {
      const c = document.createElement('canvas');
      c.width = cw; c.height = ch;
      const g = c.getContext('2d');
      g.drawImage(img, 0, 0);
      return g.getImageData(0, 0, cw, ch).data;
    };
    const S = pixels(s, s.naturalWidth, s.naturalHeight), E = pixels(e, w, h);
    const at = (d, stride, x, y) => d.subarray((y * stride + x) * 4, (y * stride + x) * 4 + 4);
    let sum = 0, n = 0, edgeSum = 0, edgeN = 0;
    for (let y = 0; y < h; y++)
      for (let x = 0; x < w; x++) {
        const q = at(E, w, x, y);
        if (q[3] < 255) continue;  // no data in the mosaic there
        const p = at(S, s.naturalWidth, x, y);
        const d = (Math.abs(p[0] - q[0]) + Math.abs(p[1] - q[1]) + Math.abs(p[2] - q[2])) / 3;
        sum += d; n++;
        if (x >= w - 24 || y >= h - 24) { edgeSum += d; edgeN++; }  // the last columns and rows
      }
    // Past the image: the page's magenta, nothing stretched over it.
    let beyond = 0, magenta = 0;
    for (let y = 0; y < s.naturalHeight; y += 3)
      for (let x = 0; x < s.naturalWidth; x += 3) {
        if (x < w + 2 && y < h + 2) continue;
        const p = at(S, s.naturalWidth, x, y);
        beyond++;
        if (p[0] > 240 && p[1] < 15 && p[2] > 240) magenta++;
      }
    return { mean: sum / Math.max(1, n), n, edge: edgeSum / Math.max(1, edgeN), edgeN, beyond, magenta };
  }, { shot: shot.toString('base64'), exported: exported.body.toString('base64'), w, h });
  check(result.n > 20000 && result.mean < 1.0,
        `Leaflet shows the stored pixels (mean |diff| ${result.mean.toFixed(2)} over ${result.n} px)`);
  check(result.edgeN > 2000 && result.edge < 1.0,
        `up to the image's last column and row, nothing stretched (mean |diff| ${result.edge.toFixed(2)} over ${result.edgeN} px)`);
  check(result.beyond > 10000 && result.magenta / result.beyond > 0.99,
        `past the image the page shows through (${result.magenta} of ${result.beyond} samples)`);
} finally {
  await browser.close();
  server.kill();
  site.close();
}
finish();
