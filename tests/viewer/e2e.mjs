// End-to-end test of the viewer in Debian's Chromium (playwright-core, no browser download):
// a store made here with the rolamos CLI, `rolamos serve` on it, the page opened, zoomed to
// one image pixel per screen pixel, panned, and what the page shows compared with the stored
// pixels (through the server's export); overlays, cursor coordinates, export of the view, a
// drawn-rectangle export and the static site of `rolamos tiles` checked too. Screenshots go to
// ARTEFACTS. Exits 77 (ctest: skipped) when Chromium or playwright-core is not installed.
//   node tests/viewer/e2e.mjs ROLAMOS_CLI SCRATCH_DIR ARTEFACTS_DIR
import { spawn, execFileSync } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import { createRequire } from 'node:module';

const [cli, scratch, artefacts] = process.argv.slice(2);
const chromiumPath = process.env.CHROMIUM || '/usr/bin/chromium';
const require = createRequire(new URL('../../viewer/package.json', import.meta.url));
let chromium;
try {
  ({ chromium } = require('playwright-core'));
} catch {
  console.log('SKIP: playwright-core is not installed (scripts/setup.sh runs npm ci in viewer/)');
  process.exit(77);
}
if (!fs.existsSync(chromiumPath)) {
  console.log('SKIP: no Chromium at ' + chromiumPath);
  process.exit(77);
}

let failures = 0;
function check(ok, what) {
  console.log((ok ? 'ok   ' : 'FAIL ') + what);
  if (!ok) failures++;
}
const pngSize = (file) => { const d = fs.readFileSync(file); return [d.readUInt32BE(16), d.readUInt32BE(20)]; };
const run = (...args) => execFileSync(cli, args, { cwd: scratch, encoding: 'utf8' });

fs.rmSync(scratch, { recursive: true, force: true });
fs.mkdirSync(scratch, { recursive: true });
fs.mkdirSync(artefacts, { recursive: true });
run('synth', '-q', '-o', 'survey', '--frames', '24', '--width', '480', '--height', '360', '--focal', '420');
run('mosaic', '-q', 'survey/frames', '-o', 's.rolamos', '--patch-megapixels', '0.6');
run('align', '-q', 's.rolamos');  // every frame's placement and confidence
run('compose', '-q', 's.rolamos');
// Detections and their density layer as `rolamos objects detect` writes them (docs/store-format.md):
// two classes, scores from -0.5 to 1.75, and a 2 x 2 grid of density cells.
{
  const objects = path.join(scratch, 's.rolamos', 'objects');
  fs.mkdirSync(objects, { recursive: true });
  const features = [];
  for (let i = 0; i < 10; i++) {
    const b = [40 + 50 * i, 60 + 20 * i, 30, 30];
    features.push({ type: 'Feature', id: i + 1, geometry: { type: 'Polygon', coordinates: [[[b[0], b[1]], [b[0] + 30, b[1]], [b[0] + 30, b[1] + 30], [b[0], b[1] + 30], [b[0], b[1]]]] },
      properties: { class: i % 2 ? 'crab' : 'burrow', score: -0.5 + 0.25 * i, image: 'mosaic', pixel_bbox: b, window_bbox: b, scores: {} } });
  }
  fs.writeFileSync(path.join(objects, 'detections.geojson'), JSON.stringify({ type: 'FeatureCollection', name: 'rolamos_detections',
    rolamos: { image: 'mosaic.tif', coordinates: 'pixel' }, features }));
  const cells = [];
  for (let k = 0; k < 4; k++) {
    const b = [(k % 2) * 256, Math.floor(k / 2) * 256, 256, 256];
    cells.push({ type: 'Feature', id: k, geometry: null, properties: { count: k, counts: {}, density: k / 0.065536, densities: {}, area: 65536, coverage: 1, pixel_bbox: b } });
  }
  fs.writeFileSync(path.join(objects, 'density.geojson'), JSON.stringify({ type: 'FeatureCollection', name: 'rolamos_density',
    rolamos: { image: 'mosaic.tif', cell_px: 256, density_unit: 'per_megapixel', area_unit: 'px' }, features: cells }));
}

const server = spawn(cli, ['serve', 's.rolamos', '--port', '0'], { cwd: scratch });
const base = await new Promise((resolve, reject) => {
  let out = '';
  server.stdout.on('data', (d) => {
    out += d;
    const m = out.match(/on (http:\/\/[^\s]+)/);
    if (m) resolve(m[1].replace(/\/$/, ''));
  });
  server.on('exit', (code) => reject(new Error('rolamos serve exited with ' + code + ': ' + out)));
});
console.log('server at ' + base);

const browser = await chromium.launch({ executablePath: chromiumPath, args: ['--no-sandbox'] });
try {
  const context = await browser.newContext({ viewport: { width: 1000, height: 700 }, acceptDownloads: true });
  const page = await context.newPage();
  const failedTiles = [];
  page.on('response', (r) => { if (r.url().includes('/dzi/') && r.status() >= 400) failedTiles.push(r.url()); });
  await page.goto(base + '/');
  const loaded = () => page.waitForFunction(() => window.rolamos && window.rolamos.ready &&
    window.rolamos.viewer.world.getItemCount() === 1 && window.rolamos.viewer.world.getItemAt(0).getFullyLoaded(),
    null, { timeout: 30000 });
  await loaded();
  const info = await page.evaluate(() => ({ images: window.rolamos.images.map((i) => i.name),
    current: window.rolamos.current.name, outlines: document.querySelectorAll('svg.overlay polygon.outline').length,
    trajectory: document.querySelectorAll('svg.overlay polyline.trajectory').length }));
  check(info.current === 'mosaic', 'opens on the global mosaic (' + info.images.join(', ') + ')');
  check(info.images.includes('patch-1') && info.images.includes('patch-2'), 'lists the patches');
  check(info.outlines === 2, 'draws the 2 patch outlines (' + info.outlines + ')');
  check(info.trajectory === 1, 'draws the trajectory');
  await page.screenshot({ path: path.join(artefacts, 'viewer-whole-map.png') });

  // One image pixel per screen pixel around a known point, then the pixels compared.
  async function compareAt(cx, cy, label) {
    await page.evaluate(([x, y]) => {
      const v = window.rolamos.viewer.viewport;
      v.zoomTo(v.imageToViewportZoom(1.0), null, true);
      v.panTo(v.imageToViewportCoordinates(x, y), true);
    }, [cx, cy]);
    // Let the viewer draw the new view before asking whether it is fully loaded.
    await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
    await loaded();
    // Fully loaded tiles are drawn on the next frames: let them be drawn before reading pixels.
    await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
    const diff = await page.evaluate(async () => {
      const r = window.rolamos;
      const canvas = r.viewer.drawer.canvas;
      const ratio = canvas.width / r.viewer.container.clientWidth;
      const w = 200, h = 200;
      const sx = Math.round(canvas.width / 2 - w / 2), sy = Math.round(canvas.height / 2 - h / 2);
      const shown = canvas.getContext('2d').getImageData(sx, sy, w, h).data;
      const tl = r.viewer.viewport.viewerElementToImageCoordinates(new OpenSeadragon.Point(sx / ratio, sy / ratio));
      const x = Math.round(tl.x), y = Math.round(tl.y);
      const img = new Image();
      img.src = 'api/export/' + r.current.name + '?region=' + [x, y, w, h].join(',') + '&format=png';
      await img.decode();
      const c = document.createElement('canvas');
      c.width = w; c.height = h;
      const g = c.getContext('2d');
      g.drawImage(img, 0, 0);
      const stored = g.getImageData(0, 0, w, h).data;
      let sum = 0, n = 0;
      for (let i = 0; i < stored.length; i += 4) {
        if (stored[i + 3] < 255) continue;  // no data there
        for (let k = 0; k < 3; k++) sum += Math.abs(stored[i + k] - shown[i + k]);
        n += 3;
      }
      return { mean: n ? sum / n : 999, samples: n / 3, ratio };
    });
    check(diff.samples > 20000 && diff.mean < 6, label + ': shown pixels = stored pixels (mean |diff| ' +
          diff.mean.toFixed(2) + ' over ' + diff.samples + ' px, JPEG tiles)');
    await page.screenshot({ path: path.join(artefacts, 'viewer-' + label + '.png') });
  }
  await compareAt(250, 600, 'full-resolution');
  const before = await page.evaluate(() => window.rolamos.tilesLoaded);
  await compareAt(260, 1500, 'after-pan');
  const after = await page.evaluate(() => window.rolamos.tilesLoaded);
  check(after > before, 'panning loads new tiles (' + before + ' -> ' + after + ')');
  check(failedTiles.length === 0, 'no tile request failed (' + failedTiles.slice(0, 3).join(' ') + ')');

  // Cursor coordinates under the mouse.
  const box = await page.locator('#map').boundingBox();
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  const cursor = await page.locator('#cursor').textContent();
  const m = cursor.match(/x ([\d.]+)\s+y ([\d.]+) px/);
  check(m && Math.abs(+m[1] - 260) < 3 && Math.abs(+m[2] - 1500) < 3, 'cursor shows the image pixel (' + cursor + ')');

  // Export of the view at full resolution, as a download.
  const [download] = await Promise.all([page.waitForEvent('download'), page.click('#export-view')]);
  const saved = path.join(artefacts, 'export-view.png');
  await download.saveAs(saved);
  const dims = pngSize(saved);
  const view = await page.evaluate(() => window.rolamos.viewRegion().map(Math.round));
  check(dims[0] > 100 && dims[1] > 100 && Math.abs(dims[1] - Math.min(view[3], 2064)) < 3,
        'export view downloads the view at full resolution (' + dims.join(' x ') + ')');

  // A drawn rectangle: press "export rectangle", drag, download.
  await page.click('#draw');
  const [rect] = await Promise.all([page.waitForEvent('download'), (async () => {
    await page.mouse.move(box.x + 300, box.y + 200);
    await page.mouse.down();
    await page.mouse.move(box.x + 400, box.y + 260, { steps: 5 });
    await page.mouse.move(box.x + 420, box.y + 280, { steps: 5 });
    await page.mouse.up();
  })()]);
  const rectFile = path.join(artefacts, 'export-rectangle.png');
  await rect.saveAs(rectFile);
  const rdims = pngSize(rectFile);
  check(Math.abs(rdims[0] - 120) <= 2 && Math.abs(rdims[1] - 80) <= 2, 'a drawn 120 x 80 rectangle downloads at 1:1 (' + rdims.join(' x ') + ')');

  // Objects: every detection, then filtered by class and by score; the density layer.
  const shown = () => page.evaluate(() => document.querySelectorAll('svg.overlay rect.detection').length);
  check(await shown() === 10, 'the mosaic shows its 10 detections (' + await shown() + ')');
  const classes = await page.evaluate(() => [...document.querySelectorAll('#object-class option')].map((o) => o.value));
  check(classes.join(',') === ',burrow,crab', 'the class filter lists the classes found (' + classes.join(',') + ')');
  await page.selectOption('#object-class', 'crab');
  check(await shown() === 5, 'filtered by class: 5 crabs (' + await shown() + ')');
  await page.selectOption('#object-class', '');
  await page.evaluate(() => { const r = document.getElementById('object-score'); r.value = '0.5'; r.dispatchEvent(new Event('input')); });
  check(await shown() === 6, 'filtered by score >= 0.5: 6 (' + await shown() + ')');
  await page.check('#show-density');
  const density = await page.evaluate(() =>
    [...document.querySelectorAll('svg.overlay rect.density')].map((r) => [getComputedStyle(r).fill, r.querySelector('title').textContent]));
  check(density.length === 4 && density[3][1].startsWith('3 objects') && density[0][0] !== density[3][0],
        'the density layer fills its 4 cells by density (' + density.map((d) => d[1]).join('; ') + ')');
  await page.screenshot({ path: path.join(artefacts, 'viewer-objects-density.png') });
  await page.uncheck('#show-density');

  // Switching to a patch shows its frame footprints.
  await page.check('#show-footprints');
  await page.selectOption('#image', 'patch-1');
  await loaded();
  const footprints = await page.evaluate(() => document.querySelectorAll('svg.overlay polygon.footprint').length);
  check(footprints > 3, 'patch-1 shows its frame footprints (' + footprints + ')');
  // The confidence layer: every frame of the aligned map filled by how sure align is of it.
  await page.check('#show-confidence');
  const conf = await page.evaluate(() =>
    [...document.querySelectorAll('svg.overlay polygon.confidence')].map((p) => getComputedStyle(p).fill));
  check(conf.length === footprints && conf.every((f) => f.startsWith('rgb')),
        'the confidence layer fills every frame by its uncertainty (' + conf.length + ' of ' + footprints + ', ' + conf[0] + ')');
  await page.uncheck('#show-confidence');
  await page.screenshot({ path: path.join(artefacts, 'viewer-patch-1.png') });

  // The static site of `rolamos tiles`, from a plain file server.
  run('tiles', '-q', 's.rolamos', '-o', 'site');
  const site = path.join(scratch, 'site');
  const types = { '.html': 'text/html', '.js': 'text/javascript', '.css': 'text/css', '.json': 'application/json', '.dzi': 'application/xml', '.jpg': 'image/jpeg' };
  const files = http.createServer((req, res) => {
    const p = path.join(site, decodeURIComponent(new URL(req.url, 'http://x').pathname));
    if (!p.startsWith(site) || !fs.existsSync(p) || fs.statSync(p).isDirectory()) { res.writeHead(404); res.end(); return; }
    res.writeHead(200, { 'Content-Type': types[path.extname(p)] || 'application/octet-stream' });
    fs.createReadStream(p).pipe(res);
  }).listen(0, '127.0.0.1');
  await new Promise((r) => files.once('listening', r));
  const page2 = await context.newPage();
  await page2.goto('http://127.0.0.1:' + files.address().port + '/index.html');
  await page2.waitForFunction(() => window.rolamos && window.rolamos.ready &&
    window.rolamos.viewer.world.getItemCount() === 1 && window.rolamos.viewer.world.getItemAt(0).getFullyLoaded(), null, { timeout: 30000 });
  const st = await page2.evaluate(() => ({ n: window.rolamos.images.length,
    outlines: document.querySelectorAll('svg.overlay polygon.outline').length }));
  check(st.n === 3 && st.outlines === 2, 'the static site opens with its images and overlays (' + JSON.stringify(st) + ')');
  await page2.screenshot({ path: path.join(artefacts, 'static-site.png') });
  files.close();
} finally {
  await browser.close();
  server.kill('SIGINT');
}
console.log(failures ? failures + ' check(s) failed' : 'all checks passed');
process.exit(failures ? 1 : 0);
