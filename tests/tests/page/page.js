// The service's web page, run under Node against a real service: its script, taken from the
// page the service serves, in a `vm` context with a small stand-in for the DOM (elements are
// plain objects that keep their children, text and handlers). Driven by
// `tests/tests/page.rs`; it prints one line of JSON per step, and fails (exit 1) on the first
// assertion that does not hold.
//
// Usage: node page.js SERVICE_URL CHECKS_JSON
//
// What it does not cover: layout, CSS, the browser's own form controls, file pickers.

"use strict";
const assert = require("node:assert/strict");
const vm = require("node:vm");
const fs = require("node:fs");
const path = require("node:path");
const { File } = require("node:buffer");

const [base, checksJson] = process.argv.slice(2);
const checks = JSON.parse(checksJson);

class Element {
  constructor(tag, id) {
    this.tagName = tag;
    this.id = id;
    this.children = [];
    this.listeners = {};
    this.textContent = "";
    this.value = "";
    this.className = "";
    this.hidden = false;
    this.files = [];
    this.onclick = null;
  }
  append(...items) {
    for (const x of items) this.children.push(typeof x === "string" ? { text: x } : x);
  }
  replaceChildren(...items) {
    this.children = [];
    this.append(...items);
  }
  addEventListener(event, f) {
    (this.listeners[event] ||= []).push(f);
  }
  // Everything this element shows as text, children included.
  get text() {
    return (this.textContent || "") + this.children.map((c) => c.text ?? "").join("");
  }
  // Depth-first search for the first descendant with this tag.
  find(tag) {
    for (const c of this.children) {
      if (c.tagName === tag) return c;
      const inner = c.find ? c.find(tag) : null;
      if (inner) return inner;
    }
    return null;
  }
}

// Every request the page makes, until its answer's body has been read.
const pending = new Set();
function track(p) {
  pending.add(p);
  p.finally(() => pending.delete(p)).catch(() => {});
  return p;
}

// Lets the page run until it has no request in flight and nothing left to do about the
// last answers (a handler that starts another request is waited for too).
async function settle() {
  for (;;) {
    await new Promise((r) => setImmediate(r));
    if (pending.size === 0) return;
    await Promise.allSettled([...pending]);
  }
}

async function main() {
  const html = await (await fetch(base + "/")).text();
  const script = html.match(/<script>([\s\S]*)<\/script>/)[1];
  const elements = {};
  for (const [, id] of html.matchAll(/\bid="([^"]+)"/g)) elements[id] = new Element("?", id);
  // The page's `hidden` attributes, as the browser would have them before the script runs.
  for (const [, id] of html.matchAll(/\bid="([^"]+)"[^>]*\bhidden\b/g)) elements[id].hidden = true;
  const storage = new Map();
  let confirmAnswer = true;
  const confirmed = [];
  const documentListeners = {};
  const context = {
    document: {
      hidden: false,
      getElementById: (id) => elements[id] ?? null,
      createElement: (tag) => new Element(tag),
      addEventListener: (event, f) => (documentListeners[event] ||= []).push(f),
    },
    localStorage: {
      getItem: (k) => (storage.has(k) ? storage.get(k) : null),
      setItem: (k, v) => storage.set(k, String(v)),
    },
    confirm: (question) => {
      confirmed.push(question);
      return confirmAnswer;
    },
    // The timer is not run: each step refreshes explicitly, so that what it sees is what
    // that step did.
    setInterval: () => 0,
    URLSearchParams,
    FormData,
    Blob,
    fetch: (url, options) =>
      track(
        fetch(url.startsWith("/") ? base + url : url, options).then(async (r) => {
          const text = await r.text();
          return {
            ok: r.ok,
            status: r.status,
            statusText: r.statusText,
            json: async () => JSON.parse(text),
          };
        }),
      ),
  };
  vm.createContext(context);
  vm.runInContext(script, context);
  const run = (code) => vm.runInContext(code, context);
  await settle();

  const rows = () => elements.jobs.children;
  // The job id or name a row starts with (its first cell).
  const firstCells = () => rows().map((tr) => tr.children[0].text);
  const api = async (path, options) => {
    const r = await fetch(base + path, options);
    return { status: r.status, body: r.status === 204 ? null : await r.json() };
  };
  const step = (name, facts) => console.log(JSON.stringify({ step: name, ...facts }));

  // 0. No worker yet; one that claims a tile is listed by name, with its tiles done.
  const workerRows = () => elements.workers.children.map((tr) => tr.children.map((td) => td.text));
  assert.deepEqual(workerRows(), [["No worker heard from in the last ten minutes."]]);
  const claim = await api("/worker/claim", {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ worker: "page-test" }),
  });
  assert.equal(claim.status, 200);
  run("refreshWorkers()");
  await settle();
  assert.equal(workerRows().length, 1);
  assert.deepEqual(workerRows()[0].slice(0, 2), ["page-test", "0"]);
  step("workers", { rows: workerRows().length });

  // 1. The newest page: PAGE rows, newest first, "older" offered, "newer" not.
  // How the list labels a job: its name and id, or its id alone.
  const label = (j) => (j.name ? `${j.name} (${j.id})` : j.id);
  const all = (await api("/jobs")).body.map(label);
  assert.equal(all.length, checks.jobs);
  assert.deepEqual(firstCells(), all.slice(0, checks.page), "newest page");
  assert.equal(elements.older.hidden, false, "older offered on a full page");
  assert.equal(elements.newer.hidden, true, "no newer page above the newest");
  step("newest page", { rows: rows().length });

  // 2. Older, twice: a full page, then the rest; and the way back, a page at a time.
  const pageOf = (n) => all.slice(n * checks.page, (n + 1) * checks.page);
  elements.older.onclick();
  await settle();
  assert.deepEqual(firstCells(), pageOf(1), "second page");
  assert.equal(elements.older.hidden, false);
  assert.equal(elements.newer.hidden, false);
  elements.older.onclick();
  await settle();
  assert.deepEqual(firstCells(), pageOf(2), "third page");
  assert.equal(elements.older.hidden, true, "a short page is the last");
  assert.equal(elements.newer.hidden, false);
  step("older pages", { rows: rows().length });
  elements.newer.onclick();
  await settle();
  assert.deepEqual(firstCells(), pageOf(1), "back to the second page");
  elements.newer.onclick();
  await settle();
  assert.deepEqual(firstCells(), pageOf(0), "back to the newest page");
  assert.equal(elements.newer.hidden, true);

  // 3. A scene submitted through the form is queued and listed first.
  elements.scene.value = checks.scene;
  elements.tile.value = String(checks.tile);
  await elements.submit.listeners.submit[0]({ preventDefault() {} });
  await settle();
  const queued = elements.msg.textContent.match(/^Job (\S+) queued: (\d+) tiles\.$/);
  assert.ok(queued, `submission message: ${elements.msg.textContent}`);
  assert.equal(elements.msg.className, "ok");
  const [, id, tiles] = queued;
  assert.equal(Number(tiles), checks.tiles, "tiles of the submitted scene");
  const job = await api("/jobs/" + id);
  assert.equal(job.status, 200);
  assert.equal(job.body.tiles_total, checks.tiles);
  assert.equal(firstCells()[0], id, "the new job heads the list");
  step("submitted", { id, tiles: Number(tiles) });

  // 4. A bad scene shows the service's error with its line and column.
  elements.scene.value = checks.bad_scene;
  await elements.submit.listeners.submit[0]({ preventDefault() {} });
  await settle();
  assert.equal(elements.msg.className, "err");
  assert.ok(
    elements.msg.textContent.startsWith(`line ${checks.bad_line}, column ${checks.bad_column}: `),
    `error message: ${elements.msg.textContent}`,
  );
  step("refused", { message: elements.msg.textContent });

  // 5. Cancelling a queued job asks nothing; deleting a finished one asks, and "no" keeps it.
  const button = () => rows()[0].children.at(-1).find("button");
  assert.equal(button().textContent, "cancel");
  const drawn = button();
  drawn.onclick();
  await settle();
  assert.equal(confirmed.length, 0, "a cancel needs no confirmation");
  assert.equal((await api("/jobs/" + id)).body.state, "cancelled");
  // The same "cancel" clicked again (a double click, or a list drawn before the job ended)
  // deletes nothing: it is a cancel, whatever the job's state now.
  drawn.onclick();
  await settle();
  assert.equal(confirmed.length, 0);
  assert.equal((await api("/jobs/" + id)).status, 200, "a repeated cancel keeps the job");
  assert.equal(button().textContent, "delete");
  confirmAnswer = false;
  button().onclick();
  await settle();
  assert.equal(confirmed.length, 1);
  assert.ok(confirmed[0].includes(id), confirmed[0]);
  assert.equal((await api("/jobs/" + id)).status, 200, "kept when the user says no");
  confirmAnswer = true;
  button().onclick();
  await settle();
  assert.equal((await api("/jobs/" + id)).status, 404, "deleted when the user says yes");
  assert.deepEqual(firstCells(), all.slice(0, checks.page), "the list without it");
  step("cancelled and deleted", { id });

  // 6. The job an older page starts after is deleted elsewhere: back to the newest page.
  elements.older.onclick();
  await settle();
  assert.equal(elements.newer.hidden, false);
  const anchor = all[checks.page - 1];
  const anchorId = (await api("/jobs")).body.find((j) => label(j) === anchor).id;
  assert.equal((await api("/jobs/" + anchorId, { method: "DELETE" })).status, 200);
  assert.equal((await api("/jobs/" + anchorId, { method: "DELETE" })).status, 200);
  assert.equal((await api("/jobs/" + anchorId + "?purge=true", { method: "DELETE" })).status, 204);
  run("refresh()");
  await settle();
  assert.equal(elements.newer.hidden, true, "back on the newest page");
  assert.equal(firstCells()[0], all[0]);
  step("anchor gone", { anchor });

  // 7. A scene file and its textures through the pickers: the file names the job, the text
  // area shows the scene, and each texture goes under the name the scene gives it.
  const read = (...parts) => fs.readFileSync(path.join(checks.examples, ...parts));
  elements.scenefile.files = [new File([read("textures.ray")], "textures.ray")];
  await elements.scenefile.listeners.change[0]();
  assert.equal(elements.scene.value, read("textures.ray").toString("utf8"));
  const textures = ["globe.png", "tile.ppm"];
  elements.assets.files = textures.map((n) => new File([read("textures", n)], n));
  elements.tile.value = "";
  await elements.submit.listeners.submit[0]({ preventDefault() {} });
  await settle();
  const withTextures = elements.msg.textContent.match(/^Job (\S+) queued: \d+ tiles\.$/);
  assert.ok(withTextures, `submission message: ${elements.msg.textContent}`);
  const textured = withTextures[1];
  assert.equal(firstCells()[0], `textures.ray (${textured})`);
  const spec = await api("/worker/jobs/" + textured);
  assert.deepEqual(spec.body.assets.sort(), textures.map((n) => "textures/" + n));
  for (const n of textures) {
    const r = await fetch(`${base}/worker/jobs/${textured}/assets/${encodeURIComponent("textures/" + n)}`);
    assert.equal(r.status, 200, n);
    assert.ok(Buffer.from(await r.arrayBuffer()).equals(read("textures", n)), `bytes of ${n}`);
  }
  step("textures", { id: textured });
}

main().catch((e) => {
  console.error(e && e.stack ? e.stack : e);
  process.exit(1);
});
