// What the browser scripts share: Debian's Chromium under Playwright, started as a machine
// without a network needs it; the service's JSON routes from Node; waiting for a condition
// with a deadline; and one line of JSON per step passed, which `tests/tests/browser.rs`
// checks.
import assert from "node:assert/strict";
import { chromium } from "playwright-core";

// Chromium's flags on a machine whose network is closed: without the background-networking
// ones it tries Google's hosts at every start.
const FLAGS = [
  "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
  "--disable-background-networking", "--disable-component-update", "--disable-sync",
];

export const base = process.env.TESSERA_URL;
export const checks = JSON.parse(process.env.TESSERA_CHECKS || "{}");

export async function browser() {
  return chromium.launch({
    executablePath: process.env.TESSERA_CHROMIUM || "/usr/bin/chromium",
    headless: true,
    args: FLAGS,
  });
}

// A fresh page (its own storage) of `width × height`, with the page's own errors collected:
// a script error or a resource the browser refused (a Content-Security-Policy violation, a
// network failure) fails the step that checks `errors`. The console's note of a 4xx answer
// is not one: the scripts provoke those on purpose.
export async function openPage(b, width = 1280, height = 900) {
  const context = await b.newContext({ viewport: { width, height } });
  const page = await context.newPage();
  page.errors = [];
  page.on("pageerror", (e) => page.errors.push(String(e)));
  page.on("console", (m) => {
    if (m.type() === "error" && !/status of 4\d\d/.test(m.text())) page.errors.push(m.text());
  });
  page.setDefaultTimeout(30_000);
  return page;
}

// A JSON route of the service from Node: `{status, body}`.
export async function api(path, options = {}) {
  const r = await fetch(base + path, options);
  const text = await r.text();
  let body = null;
  try { body = text ? JSON.parse(text) : null; } catch { body = text; }
  return { status: r.status, body, headers: r.headers };
}

// Waits for `cond()` (sync or async) to hold, asking every 50 ms, for at most `ms`.
export async function until(what, cond, ms = 60_000) {
  const end = Date.now() + ms;
  for (;;) {
    const v = await cond();
    if (v) return v;
    if (Date.now() > end) assert.fail(`timed out waiting for ${what}`);
    await new Promise((r) => setTimeout(r, 50));
  }
}

export function step(name, detail = {}) {
  console.log(JSON.stringify({ step: name, ...detail }));
}

// Runs `main`, and exits 1 (with the failure on stderr) if it throws.
export function run(main) {
  main().then(() => process.exit(0), (e) => {
    console.error(e && e.stack ? e.stack : e);
    process.exit(1);
  });
}

// Whether the page's document is wider than its viewport (something runs off the side).
export async function overflows(page) {
  return page.evaluate(() => document.documentElement.scrollWidth > window.innerWidth);
}
