// The job list in Chromium against a service with a submit token and a small body limit
// (`--submit-token`, `--max-body-bytes`, no workers, one attempt a tile): an upload over the
// limit refused before it is sent, a saved token forgotten, and what the page shows when a
// cancel or delete is refused or gets no answer. Run by `tests/tests/browser.rs`.
import assert from "node:assert/strict";
import fs from "node:fs";
import path from "node:path";
import { api, base, browser, checks, openPage, run, step, until } from "./lib.mjs";

run(async () => {
  const withToken = { Authorization: "Bearer " + checks.token };
  const read = (...p) => fs.readFileSync(path.join(checks.examples, ...p));
  const jobIds = async () => (await api("/jobs")).body.map((j) => j.id);
  const submitted = async (scene, query = "") => {
    const r = await api("/jobs" + query, { method: "POST", headers: withToken, body: scene });
    assert.equal(r.status, 201, JSON.stringify(r.body));
    return r.body.id;
  };
  const claim = async () => {
    const r = await api("/worker/claim", {
      method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ worker: "page-test" }),
    });
    assert.equal(r.status, 200, JSON.stringify(r.body));
    return r.body;
  };

  const b = await browser();
  let page = await openPage(b);
  const posts = [];
  page.on("request", (r) => { if (r.method() === "POST") posts.push(r.url()); });
  await page.goto(base + "/");
  const msg = () => page.textContent("#msg");
  const button = (id) => page.locator(`#jobs > tr[data-id="${id}"] button`);

  // 1. A scene file and its textures over the service's limit are refused before anything
  // is sent, with both sizes and where the limit comes from.
  await page.fill("#token", checks.token);
  const textures = ["globe.png", "tile.ppm"];
  await page.setInputFiles("#scenefile", path.join(checks.examples, "textures.ray"));
  await until("the scene text", async () => (await page.inputValue("#scene")).length > 0);
  await page.setInputFiles("#assets", textures.map((n) => path.join(checks.examples, "textures", n)));
  const raw = read("textures.ray").length + textures.reduce((n, t) => n + read("textures", t).length, 0);
  assert.ok(raw > checks.limit, "the files alone are over the limit");
  await page.click("button[type=submit]");
  const refusal = await until("the refusal", async () => ((await msg()).includes("--max-body-bytes") ? msg() : null));
  assert.equal(await page.getAttribute("#msg", "class"), "msg err");
  assert.ok(refusal.includes(`${checks.limit} bytes`), refusal);
  const sizes = [...refusal.matchAll(/(\d+) bytes/g)].map((m) => Number(m[1]));
  assert.ok(sizes.some((n) => n >= raw), `names the upload's size (at least ${raw}): ${refusal}`);
  assert.deepEqual(posts, [], "nothing was sent");
  assert.deepEqual(await jobIds(), []);
  step("too large");

  // 1b. Pasted text goes as a string field, whose line breaks a form sends as CRLF: 192
  // lines of 20 bytes are 3,840 bytes of text but over the limit in the body.
  await page.setInputFiles("#scenefile", []);
  await page.setInputFiles("#assets", []);
  await page.fill("#scene", "ambient = 0.1 # pad\n".repeat(192));
  await page.click("button[type=submit]");
  await until("the refusal", async () => (await msg()).includes("The scene comes"));
  assert.deepEqual(posts, [], "nothing was sent");
  step("pasted too large");

  // 2. A scene within the limit goes, with the token, which the page keeps.
  await page.fill("#scene", checks.scene);
  await page.click("button[type=submit]");
  const queued = await until("the queued message", async () => (await msg()).match(/^Job (\S+) queued: \d+ tiles\.$/));
  const id = queued[1];
  assert.equal(await page.evaluate(() => localStorage.getItem("tessera-submit-token")), checks.token);
  step("within the limit", { id });

  // 3. Clearing the token field forgets the saved token: a reloaded page has none.
  await page.fill("#token", "");
  assert.equal(await page.evaluate(() => localStorage.getItem("tessera-submit-token")), null);
  await page.reload();
  assert.equal(await page.inputValue("#token"), "", "a reloaded page has no token");
  step("token forgotten");

  // 4. A cancel without the token is refused (401): the page says so in the service's words
  // and the job stays queued. One that gets no answer says so too.
  await until("the job's row", async () => (await button(id).count()) === 1);
  assert.equal(await button(id).textContent(), "cancel");
  await button(id).click();
  await until("the refusal", async () => (await msg()).includes("needs the submit token"));
  assert.equal(await page.getAttribute("#msg", "class"), "msg err");
  assert.equal((await api("/jobs/" + id)).body.state, "queued");
  const deletes = (url) => new URL(url).pathname === "/jobs/" + id;
  await page.route(deletes, (route) => (route.request().method() === "DELETE" ? route.abort("failed") : route.continue()));
  await button(id).click();
  await until("no answer said", async () => (await msg()).includes("could not reach the service"));
  await page.unroute(deletes);
  assert.equal((await api("/jobs/" + id)).body.state, "queued");
  step("cancel refused");

  // 5. The job fails (its one tile attempt is reported failed). Deleting it asks first,
  // without mentioning an image; without the token it is refused, with it it goes.
  const failing = await claim();
  assert.equal(failing.job, id);
  const failed = await api(`/worker/jobs/${id}/tiles/${failing.idx}/fail?lease=${failing.lease}`, {
    method: "POST", headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ worker: "page-test", reason: "boom" }),
  });
  assert.equal(failed.body.job_failed, true, JSON.stringify(failed.body));
  await until("the delete button", async () => (await button(id).textContent()) === "delete");
  const asked = [];
  let answer = false;
  page.on("dialog", (d) => { asked.push(d.message()); answer ? d.accept() : d.dismiss(); });
  await button(id).click();
  await until("the question", async () => asked.length === 1);
  assert.ok(asked[0].includes(id) && !/image/i.test(asked[0]), asked[0]);
  answer = true;
  await button(id).click();
  await until("the refusal", async () => (await msg()).includes("needs the submit token") && asked.length === 2);
  assert.equal((await api("/jobs/" + id)).status, 200, "kept without the token");
  await page.fill("#token", checks.token);
  await button(id).click();
  await until("the delete", async () => (await api("/jobs/" + id)).status === 404);
  await until("the refusal replaced", async () => (await msg()) === `Job ${id} deleted.`);
  step("failed job deleted");

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
  await until("the done job's delete", async () => (await button(done).count()) === 1 && (await button(done).textContent()) === "delete");
  answer = false;
  await button(done).click();
  await until("the question", async () => asked.length === 4);
  assert.ok(asked[3].includes(done) && asked[3].includes("image"), asked[3]);
  assert.equal((await api("/jobs/" + done)).status, 200, "kept when the user says no");
  step("done job asks about its image");

  // 7. A job deleted elsewhere after the list was drawn: its cancel is answered 404, which
  // the page shows, and the next refresh drops its row.
  const gone = await submitted(checks.scene);
  await until("its row", async () => (await button(gone).count()) === 1);
  // The list stops refreshing, so that the row drawn stays while the job goes.
  await page.route((url) => new URL(url).pathname === "/jobs", (route) => route.abort("failed"));
  assert.equal((await api("/jobs/" + gone, { method: "DELETE", headers: withToken })).status, 200);
  assert.equal((await api("/jobs/" + gone + "?purge=true", { method: "DELETE", headers: withToken })).status, 204);
  const notFound = await api("/jobs/" + gone, { method: "DELETE", headers: withToken });
  assert.equal(notFound.status, 404);
  await button(gone).click();
  await until("the 404 said", async () => (await msg()) === `Could not cancel job ${gone}: ${notFound.body.error}`);
  await page.unroute((url) => new URL(url).pathname === "/jobs");
  await page.unrouteAll();
  await until("its row gone", async () => (await button(gone).count()) === 0);
  step("cancel of a job gone");
  await b.close();
});
