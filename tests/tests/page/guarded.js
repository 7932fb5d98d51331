// The service's web page against a service with a submit token and a small body limit
// (`--submit-token`, `--max-body-bytes`, no workers, one attempt a tile), in the stand-in
// browser of `harness.js`: an upload over the limit refused before it is sent, a saved token
// forgotten, and what the page shows when a cancel or delete is refused or gets no answer.
// Driven by `tests/tests/page.rs`; it prints one line of JSON per step, and fails (exit 1) on
// the first assertion that does not hold.
//
// Usage: node guarded.js SERVICE_URL CHECKS_JSON

"use strict";
const assert = require("node:assert/strict");
const fs = require("node:fs");
const path = require("node:path");
const { File } = require("node:buffer");
const { openPage, settle, api: request, step, run } = require("./harness.js");

const [base, checksJson] = process.argv.slice(2);
const checks = JSON.parse(checksJson);
const tokenKey = "tessera-submit-token";

async function main() {
  const api = (p, options) => request(base, p, options);
  const withToken = { Authorization: "Bearer " + checks.token };
  const read = (...parts) => fs.readFileSync(path.join(checks.examples, ...parts));
  // Jobs as the service lists them, ids only.
  const jobIds = async () => (await api("/jobs")).body.map((j) => j.id);
  // A job submitted straight to the service, with the token: its id.
  const submitted = async (scene, query = "") => {
    const r = await api("/jobs" + query, { method: "POST", headers: withToken, body: scene });
    assert.equal(r.status, 201, JSON.stringify(r.body));
    return r.body.id;
  };
  // Claims the next tile as a worker would.
  const claim = async () => {
    const r = await api("/worker/claim", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ worker: "page-test" }),
    });
    assert.equal(r.status, 200, JSON.stringify(r.body));
    return r.body;
  };

  let page = await openPage(base);
  let { elements } = page;
  const rowOf = (id) => elements.jobs.children.find((tr) => tr.children[0].text === id);
  const buttonOf = (id) => rowOf(id).children.at(-1).find("button");

  // 1. A scene file and its textures over the service's limit are refused before anything
  // is sent (the service would answer 413 from the length and close the connection, which
  // fetch reports as a network error), with both sizes and where the limit comes from.
  elements.token.value = checks.token;
  const textures = ["globe.png", "tile.ppm"];
  elements.scenefile.files = [new File([read("textures.ray")], "textures.ray")];
  await elements.scenefile.fire("change");
  elements.assets.files = textures.map((n) => new File([read("textures", n)], n));
  const raw = read("textures.ray").length + textures.reduce((n, t) => n + read("textures", t).length, 0);
  assert.ok(raw > checks.limit, "the files alone are over the limit");
  await page.submit();
  const refusal = elements.msg.textContent;
  assert.equal(elements.msg.className, "err", refusal);
  assert.ok(refusal.includes(`${checks.limit} bytes`), `names the limit: ${refusal}`);
  assert.ok(refusal.includes("--max-body-bytes"), `names the flag: ${refusal}`);
  const sizes = [...refusal.matchAll(/(\d+) bytes/g)].map((m) => Number(m[1]));
  assert.ok(sizes.some((n) => n >= raw), `names the upload's size (at least ${raw}): ${refusal}`);
  assert.deepEqual(page.posts(), [], "nothing was sent");
  assert.deepEqual(await jobIds(), []);
  step("too large", { message: refusal });

  // 1b. Pasted text is sent as a string field, whose line breaks a form sends as CRLF: 192
  // lines of 20 bytes are 3,840 bytes of text but 4,032 in the body, over the limit with the
  // framing (counted as text, the page sent it and showed the 413 as "could not reach").
  elements.scenefile.files = [];
  elements.assets.files = [];
  elements.scene.value = "ambient = 0.1 # pad\n".repeat(192);
  await page.submit();
  assert.equal(elements.msg.className, "err", elements.msg.textContent);
  assert.ok(elements.msg.textContent.includes("--max-body-bytes"), elements.msg.textContent);
  assert.deepEqual(page.posts(), [], "nothing was sent");
  step("pasted too large", {});

  // 2. A scene within the limit goes, with the token, which the page saves.
  elements.scenefile.files = [];
  elements.assets.files = [];
  elements.scene.value = checks.scene;
  await page.submit();
  const queued = elements.msg.textContent.match(/^Job (\S+) queued: \d+ tiles\.$/);
  assert.ok(queued, `submission message: ${elements.msg.textContent}`);
  const id = queued[1];
  assert.equal(page.storage.get(tokenKey), checks.token, "the token is saved");
  step("within the limit", { id });

  // 3. Clearing the token field forgets the saved token: a reloaded page has none.
  elements.token.value = "";
  await elements.token.fire("input");
  await elements.token.fire("change");
  assert.equal(page.storage.has(tokenKey), false, "the token is forgotten");
  page = await openPage(base, { storage: page.storage });
  ({ elements } = page);
  assert.equal(elements.token.value, "", "a reloaded page has no token");
  step("token forgotten", {});

  // 4. A cancel without the token is refused (401): the page says so, with the service's
  // words, and the job stays queued. One that gets no answer says so too.
  const msg = () => elements.msg.textContent;
  assert.equal(buttonOf(id).textContent, "cancel");
  buttonOf(id).onclick();
  await settle();
  assert.equal(elements.msg.className, "err", msg());
  assert.ok(msg().includes("needs the submit token"), `the service's error: ${msg()}`);
  assert.equal((await api("/jobs/" + id)).body.state, "queued");
  page.fault = (url, options) => (options.method === "DELETE" ? new TypeError("fetch failed") : undefined);
  buttonOf(id).onclick();
  await settle();
  page.fault = null;
  assert.equal(elements.msg.className, "err", msg());
  assert.ok(msg().startsWith("Could not reach the service"), msg());
  assert.equal((await api("/jobs/" + id)).body.state, "queued");
  step("cancel refused", { message: msg() });

  // 5. The job fails (its one tile attempt is reported failed). Deleting it asks first,
  // without mentioning an image (a failed job has none); without the token it is refused.
  const failing = await claim();
  assert.equal(failing.job, id);
  const failed = await api(`/worker/jobs/${id}/tiles/${failing.idx}/fail?lease=${failing.lease}`, {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ worker: "page-test", reason: "boom" }),
  });
  assert.equal(failed.body.job_failed, true, JSON.stringify(failed.body));
  page.run("refresh()");
  await settle();
  assert.equal(buttonOf(id).textContent, "delete");
  page.confirmAnswer = false;
  buttonOf(id).onclick();
  await settle();
  assert.equal(page.confirmed.length, 1);
  assert.ok(page.confirmed[0].includes(id), page.confirmed[0]);
  assert.ok(!/image/i.test(page.confirmed[0]), `a failed job has no image: ${page.confirmed[0]}`);
  page.confirmAnswer = true;
  buttonOf(id).onclick();
  await settle();
  assert.ok(msg().includes("needs the submit token"), `the service's error: ${msg()}`);
  assert.equal((await api("/jobs/" + id)).status, 200, "kept without the token");
  // With the token it goes, and the refusal shown for it goes too.
  elements.token.value = checks.token;
  buttonOf(id).onclick();
  await settle();
  assert.equal((await api("/jobs/" + id)).status, 404, "deleted with the token");
  assert.equal(msg(), "", "the refusal is no longer shown");
  step("failed job deleted", { id });

  // 6. A done job's delete asks about its image.
  const small = checks.scene.replace("width = 640\nheight = 480", "width = 16\nheight = 16");
  const done = await submitted(small, "?tile=16");
  const tile = await claim();
  assert.deepEqual([tile.job, tile.w, tile.h], [done, 16, 16]);
  const blob = Buffer.alloc(20 + 16 * 16 * 3, 0x80);
  blob.write("TSR1", 0, "latin1");
  [tile.x, tile.y, tile.w, tile.h].forEach((v, i) => blob.writeUInt32LE(v, 4 + 4 * i));
  const put = await api(`/worker/jobs/${done}/tiles/${tile.idx}?lease=${tile.lease}`, { method: "PUT", body: blob });
  assert.equal(put.status, 200, JSON.stringify(put.body));
  assert.equal((await api(`/jobs/${done}?wait=30`)).body.state, "done");
  page.run("refresh()");
  await settle();
  page.confirmAnswer = false;
  const confirms = page.confirmed.length;
  buttonOf(done).onclick();
  await settle();
  assert.equal(page.confirmed.length, confirms + 1);
  const asked = page.confirmed.at(-1);
  assert.ok(asked.includes(done) && asked.includes("image"), asked);
  assert.equal((await api("/jobs/" + done)).status, 200, "kept when the user says no");
  page.confirmAnswer = true;
  step("done job asks about its image", { id: done });

  // 7. A job deleted elsewhere after the list was drawn: its cancel is answered 404, which
  // the page shows, and the next refresh drops its row.
  const gone = await submitted(checks.scene);
  page.run("refresh()");
  await settle();
  const drawn = buttonOf(gone);
  assert.equal(drawn.textContent, "cancel");
  assert.equal((await api("/jobs/" + gone, { method: "DELETE", headers: withToken })).status, 200);
  assert.equal((await api("/jobs/" + gone + "?purge=true", { method: "DELETE", headers: withToken })).status, 204);
  const notFound = await api("/jobs/" + gone, { method: "DELETE", headers: withToken });
  assert.equal(notFound.status, 404);
  drawn.onclick();
  await settle();
  assert.equal(elements.msg.className, "err", msg());
  assert.equal(msg(), `Could not cancel job ${gone}: ${notFound.body.error}`);
  assert.equal(rowOf(gone), undefined, "its row is gone");
  step("cancel of a job gone", { message: msg() });
}

run(main);
