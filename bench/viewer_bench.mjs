// How smoothly the viewer shows a map, in Debian's Chromium: for a store's image, the page is
// opened, then moved to 1:1 at random places (as a user zooming into details); each time, the
// time until the view is fully drawn. Median and worst of N moves; run for a 10-megapixel and a
// 10-gigapixel store to compare. SERVE_ARGS adds options to `rolamos serve`.
//   node bench/viewer_bench.mjs ROLAMOS_CLI STORE [moves]
import { spawn } from 'node:child_process';
import { createRequire } from 'node:module';

const [cli, store, movesArg] = process.argv.slice(2);
const moves = Number(movesArg || 20);
const require = createRequire(new URL('../viewer/package.json', import.meta.url));
const { chromium } = require('playwright-core');
const server = spawn(cli, ['serve', store, '--port', '0', ...(process.env.SERVE_ARGS ? process.env.SERVE_ARGS.split(' ') : [])]);
const base = await new Promise((resolve) => {
  let out = '';
  server.stdout.on('data', (d) => { out += d; const m = out.match(/on (http:\/\/[^\s]+)/); if (m) resolve(m[1]); });
});
const browser = await chromium.launch({ executablePath: '/usr/bin/chromium', args: ['--no-sandbox'] });
try {
  const page = await (await browser.newContext({ viewport: { width: 1280, height: 800 } })).newPage();
  // Routing turns Chromium's HTTP cache off: every move fetches its tiles from the server, as a
  // first visit to each place does, whatever the size of the map.
  await page.route('**', (route) => route.continue());
  const t0 = Date.now();
  await page.goto(base);
  const loaded = () => page.waitForFunction(() => window.rolamos && window.rolamos.ready &&
    window.rolamos.viewer.world.getItemCount() === 1 && window.rolamos.viewer.world.getItemAt(0).getFullyLoaded(),
    null, { timeout: 60000, polling: 'raf' });
  await loaded();
  const first = Date.now() - t0;
  const size = await page.evaluate(() => [window.rolamos.current.width, window.rolamos.current.height]);
  const times = [], again = [];
  let seed = 7;
  const rnd = () => (seed = (seed * 1103515245 + 12345) % 2147483648) / 2147483648;
  const places = [];
  for (let i = 0; i < moves; i++) places.push([640 + rnd() * (size[0] - 1280), 400 + rnd() * (size[1] - 800)]);
  // Each place twice: first visit (tiles cold in the server's cache on a big map), then revisit.
  for (let i = 0; i < 2 * moves; i++) {
    const [x, y] = places[i % moves];
    const t = Date.now();
    await page.evaluate(([x, y]) => {
      // Forget the tiles already drawn, so every move loads its view afresh on both maps.
      window.rolamos.viewer.world.resetItems();
      const v = window.rolamos.viewer.viewport;
      v.zoomTo(v.imageToViewportZoom(1.0), null, true);
      v.panTo(v.imageToViewportCoordinates(x, y), true);
    }, [x, y]);
    await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
    await loaded();
    (i < moves ? times : again).push(Date.now() - t);
  }
  const median = (a) => [...a].sort((p, q) => p - q)[Math.floor(a.length / 2)];
  console.log(JSON.stringify({ store, width: size[0], height: size[1], whole_map_ms: first,
    first_visit_median_ms: median(times), first_visit_max_ms: Math.max(...times),
    revisit_median_ms: median(again), revisit_max_ms: Math.max(...again), moves }));
} finally {
  await browser.close();
  server.kill('SIGINT');
}
