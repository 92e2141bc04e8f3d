// Live latency as the pilot sees it: from a frame written into the watched folder to its footprint
// in the page of `rolamos mosaic --live --serve` (Debian's Chromium through playwright-core). A
// logger writes 1292 x 964 frames at a camera's rate; the page, left to follow the run, is sampled
// every 50 ms for the frame whose footprint it shows. A frame's latency is the time until the page
// shows it or a later frame (a frame superseded between two polls is shown through the later one).
// Also: frames skipped and coverage lost (STORE/live/status.json), CPU use and peak memory of the
// process. With --minutes M, one long run at 10 frames/s (the survey fed over and over under new
// names) samples the process's memory every 10 s: it must stay flat.
//
//   node bench/live_latency.mjs [--cli build/rolamos] [--out bench/out/live-latency] [--runs 3]
//                               [--minutes 0]
// Medians over the runs. Needs `npm ci` in viewer/ (playwright-core) and /usr/bin/chromium.
import { spawn, execFileSync } from 'node:child_process';
import fs from 'node:fs';
import path from 'node:path';
import { createRequire } from 'node:module';

const args = Object.fromEntries(process.argv.slice(2).reduce((a, v, i, all) =>
  (v.startsWith('--') ? a.concat([[v.slice(2), all[i + 1]]]) : a), []));
const root = path.resolve(path.dirname(new URL(import.meta.url).pathname), '..');
const cli = path.resolve(args.cli || path.join(root, 'build/rolamos'));
const out = path.resolve(args.out || path.join(root, 'bench/out/live-latency'));
const runs = parseInt(args.runs || '3', 10);
const minutes = parseFloat(args.minutes || '0');
const require = createRequire(path.join(root, 'viewer/package.json'));
const { chromium } = require('playwright-core');
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const median = (v) => { const s = v.slice().sort((a, b) => a - b); return s.length ? s[Math.floor(s.length / 2)] : NaN; };
const quantile = (v, q) => { const s = v.slice().sort((a, b) => a - b); return s[Math.min(s.length - 1, Math.floor(s.length * q))]; };

fs.mkdirSync(out, { recursive: true });
// The surveys: stills at 80 % overlap (a stills camera at 10 frames/s) and camera-rate video
// frames (95 %), both 1292 x 964, made once with the CLI.
function survey(name, extra) {
  const dir = path.join(out, name);
  if (!fs.existsSync(path.join(dir, 'frames'))) execFileSync(cli, ['synth', '-q', '-o', dir, ...extra]);
  return fs.readdirSync(path.join(dir, 'frames')).sort().map((f) => path.join(dir, 'frames', f));
}
const stills = survey('stills-1292', ['--frames', '200', '--overlap', '0.8', '--path', 'lawnmower']);
const video = survey('video-1292', ['--frames', '300', '--overlap', '0.95', '--path', 'lawnmower']);

function procStat(pid) {
  try {
    const st = fs.readFileSync(`/proc/${pid}/stat`, 'utf8').split(') ')[1].split(' ');
    const rss = parseInt(fs.readFileSync(`/proc/${pid}/status`, 'utf8').match(/VmRSS:\s+(\d+)/)[1], 10) / 1024;
    const hz = 100;
    return { cpu: (parseInt(st[11], 10) + parseInt(st[12], 10)) / hz, rss };
  } catch { return null; }
}

async function oneRun(browser, frames, fps, work, { loopFor = 0 } = {}) {
  fs.rmSync(work, { recursive: true, force: true });
  fs.mkdirSync(path.join(work, 'incoming'), { recursive: true });
  const proc = spawn(cli, ['mosaic', '-q', 'incoming', '-o', 'live.rolamos', '--live', '--serve', '0', '--idle-timeout', '4'],
                     { cwd: work });
  let log = '';
  proc.stdout.on('data', (d) => { log += d; });
  proc.stderr.on('data', (d) => { log += d; });
  const exited = new Promise((resolve) => proc.on('exit', (code) => resolve(code)));
  const base = await new Promise((resolve, reject) => {
    const t = setInterval(() => { const m = log.match(/viewer on (http:\/\/[^\s]+)/); if (m) { clearInterval(t); resolve(m[1]); } }, 20);
    exited.then((c) => reject(new Error('mosaic --live exited with ' + c + ': ' + log)));
  });
  const page = await browser.newPage({ viewport: { width: 1000, height: 700 } });
  await page.goto(base);
  await page.evaluate(() => {
    window.seen = [];
    setInterval(() => {
      const v = window.rolamos.liveView && window.rolamos.liveView.view;
      if (v && v.last_frame) window.seen.push([Date.now(), v.last_frame.source.split('/').pop()]);
    }, 50);
  });
  await sleep(500);
  const written = [];  // [time, name]
  const memory = [];
  const cpu0 = procStat(proc.pid);
  const t0 = Date.now();
  let i = 0;
  const end = loopFor > 0 ? t0 + loopFor * 1000 : 0;
  for (;;) {
    if (loopFor > 0 ? Date.now() >= end : i >= frames.length) break;
    const name = loopFor > 0 ? `f${String(i).padStart(7, '0')}.jpg` : path.basename(frames[i]);
    fs.copyFileSync(frames[i % frames.length], path.join(work, 'incoming/.incoming'));
    fs.renameSync(path.join(work, 'incoming/.incoming'), path.join(work, 'incoming', name));
    written.push([Date.now(), name]);
    i++;
    if (loopFor > 0 && i % (10 * fps) === 0) {
      const s = procStat(proc.pid);
      if (s) memory.push([(Date.now() - t0) / 1000, s.rss]);
      // Old frames removed, as a logger's disk would be managed; the store keeps the map.
      for (const [, n] of written.slice(Math.max(0, written.length - 20 * fps), written.length - 10 * fps))
        fs.rmSync(path.join(work, 'incoming', n), { force: true });
    }
    const wait = t0 + (i * 1000) / fps - Date.now();
    if (wait > 0) await sleep(wait);
  }
  await sleep(2500);  // the last frames reach the page
  const seen = await page.evaluate(() => window.seen);
  const cpu1 = procStat(proc.pid);
  await page.close();
  proc.kill('SIGINT');
  const code = await exited;
  if (code !== 0) throw new Error('mosaic --live failed: ' + log);
  const status = JSON.parse(fs.readFileSync(path.join(work, 'live.rolamos/live/status.json'), 'utf8'));
  const order = new Map(written.map(([, n], k) => [n, k]));
  // For each frame, the first sample showing it or a later one.
  const latencies = [], steady = [];
  let s = -1, shown = -1, unseen = 0;
  for (let k = 0; k < written.length; k++) {
    while (shown < k && s + 1 < seen.length) { s++; shown = Math.max(shown, order.get(seen[s][1]) ?? -1); }
    if (shown >= k) {
      latencies.push(seen[s][0] - written[k][0]);
      // After the start: the first 24 frames wait for the overlay search (--mask auto).
      if (k >= 30) steady.push(seen[s][0] - written[k][0]);
    } else unseen++;
  }
  const peak = parseFloat((log.match(/peak memory (\d+) MiB/) || [0, 'NaN'])[1]);
  const seconds = (Date.now() - t0) / 1000;
  return { p50: quantile(latencies, 0.5) / 1000, p95: quantile(latencies, 0.95) / 1000,
           p95steady: quantile(steady, 0.95) / 1000, unseen, fed: written.length,
           skipped: status.frames_skipped, lost: status.coverage_lost, registered: status.frames_registered,
           cpu: cpu0 && cpu1 ? 100 * (cpu1.cpu - cpu0.cpu) / seconds / 2 : NaN, peak, memory };
}

const browser = await chromium.launch({ executablePath: process.env.CHROMIUM || '/usr/bin/chromium', args: ['--no-sandbox'] });
const lines = [];
try {
  if (minutes > 0) {
    const r = await oneRun(browser, stills, 10, path.join(out, 'long'), { loopFor: minutes * 60 });
    lines.push(`${minutes}-minute live run, stills 1292 x 964 at 10 frames/s: ${r.fed} frames, ${r.skipped} skipped, ` +
               `coverage lost ${r.lost}; latency p50 ${r.p50.toFixed(2)} s, p95 ${r.p95.toFixed(2)} s; CPU ${r.cpu.toFixed(0)} % of 2 cores`);
    lines.push('RSS (MiB) over time: ' + r.memory.map(([t, m]) => `${t.toFixed(0)} s ${m.toFixed(0)}`).join(', '));
  } else {
    lines.push('| feed | frames fed | skipped | coverage lost | latency p50 / p95 (s) | p95 after frame 30 (s) | not shown | CPU % of 2 cores | peak MiB |');
    lines.push('|---|---|---|---|---|---|---|---|---|');
    for (const [name, frames, fps] of [['stills 1292 x 964', stills, 10], ['stills 1292 x 964', stills, 30],
                                        ['video 1292 x 964', video, 30]]) {
      const all = [];
      for (let k = 0; k < runs; k++) all.push(await oneRun(browser, frames, fps, path.join(out, 'run')));
      const m = (key) => median(all.map((r) => r[key]));
      lines.push(`| ${name} at ${fps} frames/s | ${m('fed')} | ${m('skipped')} | ${m('lost')} | ${m('p50').toFixed(2)} / ` +
                 `${m('p95').toFixed(2)} | ${m('p95steady').toFixed(2)} | ${m('unseen')} | ${m('cpu').toFixed(0)} | ${m('peak').toFixed(0)} |`);
      console.log(lines[lines.length - 1]);
    }
  }
} finally {
  await browser.close();
}
console.log(lines.join('\n'));
fs.writeFileSync(path.join(out, minutes > 0 ? 'long.md' : 'latency.md'), lines.join('\n') + '\n');
