// The map page (/map.html) in Debian's Chromium: a survey georeferenced from its navigation, its
// Web Mercator tiles in Leaflet, and no request leaving for another host unless a base map is
// configured; with `rolamos serve --basemap URL` the base map's tiles are asked for beneath it
// (a base map served here, standing in for OpenStreetMap or a chart server).
// Exits 77 (ctest: skipped) without Chromium or playwright-core.
//   node tests/viewer/map_e2e.mjs ROLAMOS_CLI SCRATCH_DIR ARTEFACTS_DIR
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';

import { check, chromiumOrSkip, finish, launch, serve } from './support.mjs';

const [cli, scratch, artefacts] = process.argv.slice(2);
const chromium = chromiumOrSkip();
const run = (...args) => execFileSync(cli, args, { cwd: scratch, encoding: 'utf8' });

fs.rmSync(scratch, { recursive: true, force: true });
fs.mkdirSync(scratch, { recursive: true });
fs.mkdirSync(artefacts, { recursive: true });
run('synth', '-q', '-o', 'survey', '--frames', '16', '--width', '480', '--height', '360', '--focal', '420');
// The vehicle's navigation from the survey's ground truth: texture pixel (X, Y) is
// (500000 + 0.01 X, 5200000 - 0.01 Y) in UTM zone 55 south (EPSG:32755).
const truth = JSON.parse(fs.readFileSync(path.join(scratch, 'survey/ground_truth.json')));
const [fw, fh] = truth.frame_size;
let csv = 'frame,easting,northing,epsg,altitude,heading\n';
for (const f of truth.frames) {
  const H = f.frame_to_world;
  const world = (x, y) => { const z = H[6] * x + H[7] * y + H[8];
    return [500000 + 0.01 * (H[0] * x + H[1] * y + H[2]) / z, 5200000 - 0.01 * (H[3] * x + H[4] * y + H[5]) / z]; };
  const cx = (fw - 1) / 2, cy = (fh - 1) / 2;
  const c = world(cx, cy), up = world(cx, cy - 1), right = world(cx + 1, cy);
  const heading = Math.atan2(up[0] - c[0], up[1] - c[1]) * 180 / Math.PI;
  csv += `${path.basename(f.file)},${c[0]},${c[1]},32755,${Math.hypot(right[0] - c[0], right[1] - c[1]) * 420},${heading}\n`;
}
fs.writeFileSync(path.join(scratch, 'nav.csv'), csv);
run('mosaic', '-q', 'survey/frames', '-o', 's.rolamos');
run('compose', '-q', 's.rolamos', '--navigation', 'nav.csv', '--focal', '420');
run('export', '-q', 's.rolamos', '--scale', '0.1', '-o', 'base.png');

// A base-map server of our own: every tile the same picture, and a count of what was asked.
let baseRequests = 0;
const baseTile = fs.readFileSync(path.join(scratch, 'base.png'));
const site = http.createServer((req, res) => {
  baseRequests++;
  res.setHeader('Content-Type', 'image/png');
  res.end(baseTile);
}).listen(0, '127.0.0.1');
await new Promise((r) => site.on('listening', r));
const basemap = `http://127.0.0.1:${site.address().port}/base/{z}/{x}/{y}.png`;

const browser = await launch(chromium);
try {
  for (const withBase of [false, true]) {
    const label = withBase ? 'with --basemap' : 'without a base map';
    const { server, base } = await serve(cli, 's.rolamos', scratch,
                                        withBase ? ['--basemap', basemap, '--basemap-attribution', 'test charts'] : []);
    const context = await browser.newContext({ viewport: { width: 900, height: 600 } });
    const tab = await context.newPage();
    const hosts = new Set(), mosaicTiles = [];
    tab.on('request', (r) => hosts.add(new URL(r.url()).host));
    tab.on('response', (r) => { if (r.url().includes('/webmercator/')) mosaicTiles.push(r.status()); });
    const before = baseRequests;
    await tab.goto(base + '/');
    await tab.waitForFunction(() => !document.getElementById('map-link').hidden, null, { timeout: 20000 });
    check(true, label + ': the pixel viewer links to the map page (the mosaic is on Earth)');
    await tab.goto(base + '/map.html');
    await tab.waitForFunction(() => window.rolamosMap && window.rolamosMap.ready, null, { timeout: 20000 });
    await tab.waitForFunction(() => {
      const imgs = [...document.querySelectorAll('img.leaflet-tile')];
      return imgs.length > 0 && imgs.every((i) => i.complete);
    }, null, { timeout: 20000 });
    await tab.screenshot({ path: path.join(artefacts, 'map-' + (withBase ? 'basemap' : 'alone') + '.png') });
    check(mosaicTiles.length > 0 && mosaicTiles.every((s) => s === 200),
          `${label}: the mosaic's Web Mercator tiles load (${mosaicTiles.length}, statuses ${[...new Set(mosaicTiles)]})`);
    const own = new URL(base).host;
    if (withBase) {
      check(baseRequests > before, `${label}: the base map's tiles are asked for (${baseRequests - before})`);
      check(await tab.evaluate(() => document.querySelector('.leaflet-control-attribution').textContent.includes('test charts')),
            `${label}: the base map's attribution is shown`);
    } else {
      check(baseRequests === before && [...hosts].every((h) => h === own),
            `${label}: nothing is fetched from elsewhere (hosts: ${[...hosts].join(', ')})`);
    }
    await context.close();
    server.kill();
  }
} finally {
  await browser.close();
  site.close();
}
finish();
