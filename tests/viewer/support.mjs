// What the browser tests share: Debian's Chromium through playwright-core (no browser download),
// skipped (exit 77, ctest's "skipped") when either is missing; checks that count failures; and a
// `rolamos serve` started on a store, its URL read from what it prints.
import { spawn } from 'node:child_process';
import fs from 'node:fs';
import { createRequire } from 'node:module';

export const chromiumPath = process.env.CHROMIUM || '/usr/bin/chromium';
export const requireViewer = createRequire(new URL('../../viewer/package.json', import.meta.url));

// playwright-core's chromium, or the process ends with 77 saying why.
export function chromiumOrSkip() {
  let chromium;
  try {
    ({ chromium } = requireViewer('playwright-core'));
  } catch {
    console.log('SKIP: playwright-core is not installed (scripts/setup.sh runs npm ci in viewer/)');
    process.exit(77);
  }
  if (!fs.existsSync(chromiumPath)) {
    console.log('SKIP: no Chromium at ' + chromiumPath);
    process.exit(77);
  }
  return chromium;
}

// Headless Chromium as this machine's closed network wants it.
export function launch(chromium) {
  return chromium.launch({
    executablePath: chromiumPath,
    args: ['--no-sandbox', '--disable-gpu', '--disable-background-networking', '--disable-component-update'],
  });
}

let failures = 0;
export function check(ok, what) {
  console.log((ok ? 'ok   ' : 'FAIL ') + what);
  if (!ok) failures++;
}
export function finish() {
  console.log(failures ? `${failures} check(s) failed` : 'all checks passed');
  process.exit(failures ? 1 : 0);
}

// `rolamos serve STORE --port 0 ...extra` in `cwd`: the process and its base URL.
export async function serve(cli, store, cwd, extra = []) {
  const server = spawn(cli, ['serve', store, '--port', '0', ...extra], { cwd });
  const base = await new Promise((resolve, reject) => {
    let out = '';
    server.stdout.on('data', (d) => {
      out += d;
      const m = out.match(/on (http:\/\/[^\s]+)/);
      if (m) resolve(m[1].replace(/\/$/, ''));
    });
    server.on('exit', (code) => reject(new Error('rolamos serve exited with ' + code + ': ' + out)));
  });
  return { server, base };
}
