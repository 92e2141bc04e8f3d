// The live page in Debian's Chromium (playwright-core): a logger writes a synthetic survey's
// frames into a folder at 10 frames/s while `rolamos mosaic --live --serve 0` maps them and serves
// the viewer from the same process. The page must follow the run without a reload: the open
// patch's preview, the track and the patch count grow while frames arrive, the current frame's
// footprint is drawn, and what the page shows of the preview is the seafloor (not an empty
// canvas). SIGINT then ends the run with the open patch written. Screenshots go to ARTEFACTS.
// Exits 77 (ctest: skipped) when Chromium or playwright-core is not installed.
//   node tests/viewer/live_e2e.mjs ROLAMOS_CLI SCRATCH_DIR ARTEFACTS_DIR
import { spawn, execFileSync } from 'node:child_process';
import fs from 'node:fs';
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
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

fs.rmSync(scratch, { recursive: true, force: true });
fs.mkdirSync(path.join(scratch, 'incoming'), { recursive: true });
fs.mkdirSync(artefacts, { recursive: true });
execFileSync(cli, ['synth', '-q', '-o', 'survey', '--frames', '90', '--width', '640', '--height', '480', '--lanes', '2'],
             { cwd: scratch });
const frames = fs.readdirSync(path.join(scratch, 'survey/frames')).sort();

const run = spawn(cli, ['mosaic', '-q', 'incoming', '-o', 'live.rolamos', '--live', '--serve', '0',
                        '--patch-megapixels', '1.5', '--preview-interval', '1'], { cwd: scratch });
let out = '';
run.stdout.on('data', (d) => { out += d; });
run.stderr.on('data', (d) => { out += d; });
const exited = new Promise((resolve) => run.on('exit', (code, signal) => resolve({ code, signal })));
const base = await new Promise((resolve, reject) => {
  const poll = setInterval(() => {
    const m = out.match(/viewer on (http:\/\/[^\s]+)/);
    if (m) { clearInterval(poll); resolve(m[1].replace(/\/$/, '')); }
  }, 50);
  exited.then((e) => reject(new Error('rolamos mosaic --live exited with ' + JSON.stringify(e) + ': ' + out)));
});
console.log('viewer at ' + base);

let logger = Promise.resolve(), fed = 0;
const browser = await chromium.launch({ executablePath: chromiumPath, args: ['--no-sandbox'] });
try {
  const page = await browser.newPage({ viewport: { width: 900, height: 700 } });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  // The layers' descriptors come 300 ms late, as over a ship's network to the vehicle: the user's
  // choices below land while the page is adding layers.
  await page.route('**/dzi/*.dzi*', async (route) => { await sleep(300); await route.continue(); });
  await page.goto(base + '/');
  // The logger: 10 frames/s, each written under a temporary name and renamed, as loggers do. It
  // starts once the page is open, so the run does not share the cores with Chromium's start-up
  // while frames arrive (CI's run once mapped the feed seconds late).
  logger = (async () => {
    for (const f of frames) {
      fs.copyFileSync(path.join(scratch, 'survey/frames', f), path.join(scratch, 'incoming/.incoming'));
      fs.renameSync(path.join(scratch, 'incoming/.incoming'), path.join(scratch, 'incoming', f));
      fed++;
      await sleep(100);
    }
  })();
  // What the page shows, sampled while frames arrive.
  const seen = [];
  const sample = () => page.evaluate(() => {
    const r = window.rolamos, lv = r.liveView;
    const track = document.querySelector('svg.overlay polyline.trajectory');
    return {
      live: !!(r.current && r.current.live), version: lv ? lv.version : null, patch: lv && lv.view ? lv.view.patch : 0,
      track: track ? track.getAttribute('points').trim().split(' ').length : 0,
      footprint: document.querySelectorAll('svg.overlay polygon.current-frame').length,
      patches: r.live ? r.live.patches : 0, items: r.viewer.world.getItemCount(),
      text: document.getElementById('live').textContent,
    };
  });
  // Sampled until the run has received every frame the logger wrote: on a loaded machine (CI
  // once started Chromium beside it) the run maps the feed seconds after it arrives. A minute at
  // most, for a run that never catches up.
  const received = (s) => { const m = /live: (\d+) frames/.exec(s.text); return m ? parseInt(m[1], 10) : 0; };
  // Every few seconds the user looks at the last closed patch and comes back to "live": the page
  // drops the layers it was adding for the live view (OpenSeadragon does so when it opens an
  // image) and must build the view anew, not wait on them (it once stopped following there).
  const choose = (which) => page.evaluate((which) => {
    const select = document.getElementById('image');
    const names = [...select.options].map((o) => o.value);
    const name = which === 'live' ? names.find((n) => n === 'live') : names.filter((n) => n.startsWith('patch')).pop();
    if (!name) return false;
    select.value = name;
    select.dispatchEvent(new Event('change'));
    return true;
  }, which);
  let chosen = 0;
  for (let i = 0; i < 240; i++) {
    await sleep(250);
    if (i % 12 === 6 && (await choose('patch'))) { await sleep(300); if (await choose('live')) chosen++; }
    const s = await sample();
    seen.push(s);
    if (fed >= frames.length && received(s) >= frames.length) break;
  }
  const last = seen.length ? received(seen[seen.length - 1]) : 0;
  check(last >= frames.length, 'the page\'s status followed the run to its last frame (' + last + ' of ' + frames.length + ')');
  check(chosen >= 2, 'the user went to a closed patch and back to "live" while frames arrived (' + chosen + ' times)');
  const during = seen.filter((s) => s.live);
  check(during.length > 5, 'the page shows the live view while frames arrive (' + during.length + ' of ' + seen.length + ' samples)');
  const versions = new Set(during.map((s) => s.version));
  check(versions.size >= 3, 'the open patch\'s preview was refreshed without a reload (' + versions.size + ' versions)');
  const tracks = during.map((s) => s.track);
  check(tracks.length && Math.max(...tracks) > Math.min(...tracks), 'the track grows (' + Math.min(...tracks) + ' -> ' + Math.max(...tracks) + ' points)');
  const patches = seen.map((s) => s.patches);
  check(Math.max(...patches) > Math.min(...patches), 'the patch count grows (' + Math.min(...patches) + ' -> ' + Math.max(...patches) + ')');
  check(during.some((s) => s.footprint === 1), 'the current frame\'s footprint is drawn');
  check(during.some((s) => s.items >= 2), 'closed patches are shown beneath the open one (' + Math.max(...during.map((s) => s.items)) + ' layers)');
  // The preview is seafloor: the view's centre (the vehicle, when following) is not empty. The
  // page rebuilds its world when a patch opens and refreshes the preview once a second, so the
  // centre is looked at until the page has settled on the last frames (CI once caught it between
  // a new patch's world and its first tiles); it must show texture within 20 s of the feed's end.
  await logger;
  const centreOf = () => page.evaluate(() => {
    const lv = window.rolamos.liveView;
    if (!lv || !lv.preview || !lv.preview.getFullyLoaded()) return null;
    const c = document.querySelector('#map canvas');
    const g = c.getContext('2d');
    const d = g.getImageData(c.width / 2 - 40, c.height / 2 - 40, 80, 80).data;
    let sum = 0, sum2 = 0, n = 0;
    for (let i = 0; i < d.length; i += 4) { const v = (d[i] + d[i + 1] + d[i + 2]) / 3; sum += v; sum2 += v * v; n++; }
    const mean = sum / n;
    return { mean, sd: Math.sqrt(Math.max(0, sum2 / n - mean * mean)) };
  });
  let centre = { sd: 0 };
  for (let waited = 0; waited < 20000; waited += 250) {
    centre = (await centreOf()) || { sd: 0 };
    if (centre.sd > 5) break;
    await sleep(250);
  }
  const shot = path.join(artefacts, 'viewer-live.png');
  await page.screenshot({ path: shot });
  check(centre.sd > 5, 'the view around the vehicle shows textured seafloor (grey sd ' + centre.sd.toFixed(1) + ')');
  if (centre.sd <= 5) {
    console.log('the live view then: ' + await page.evaluate(() => {
      const r = window.rolamos, lv = r.liveView;
      return JSON.stringify({ current: r.current && r.current.name, follow: document.getElementById('follow').checked,
        view: !!(lv && lv.view), preview: !!(lv && lv.preview), loaded: !!(lv && lv.preview && lv.preview.getFullyLoaded()),
        missing: lv ? lv.missing.length : null, items: r.viewer.world.getItemCount(),
        status: document.getElementById('status').textContent });
    }));
  }
  check(errors.length === 0, 'no page errors' + (errors.length ? ': ' + errors.join('; ') : ''));
  console.log('last sample: ' + JSON.stringify(seen[seen.length - 1]));
} finally {
  await browser.close();
  await logger;
  await sleep(1500);
  run.kill('SIGINT');
}
const end = await exited;
check(end.code === 0, 'SIGINT ended the run cleanly (' + JSON.stringify(end) + ')');
check(/stopped by a signal, the open patch written/.test(out), 'the open patch was written');
const preview = JSON.parse(fs.readFileSync(path.join(scratch, 'live.rolamos/live/preview.json'), 'utf8'));
check(preview.patch === 0, 'after the run the preview says that no patch is open');
if (failures) {
  console.log(out);
  process.exit(1);
}
console.log('all live viewer checks passed');
