// The job list (`/`) in Chromium, against a service with no token, no workers and the
// default body limit, holding `checks.jobs` queued jobs: the list a page at a time, a
// submission through the form, a refused scene's line and column, cancel and delete, a job
// an older page starts after deleted elsewhere, a scene file with its textures, a chosen
// file sent as its own bytes unless edited, a list that cannot be loaded, and a phone's
// width. Run by `tests/tests/browser.rs`.
import assert from "node:assert/strict";
import fs from "node:fs";
import path from "node:path";
import { api, base, browser, checks, openPage, overflows, run, step, until } from "./lib.mjs";

run(async () => {
  const b = await browser();
  const page = await openPage(b);
  await page.goto(base + "/");
  const rows = page.locator("#jobs > tr");
  // The first cell of each row: the job's name and id, or its id.
  const firstCells = () => page.$$eval("#jobs > tr", (trs) => trs.map((tr) => tr.children[0].textContent));
  const label = (j) => (j.name ? `${j.name} (${j.id})` : j.id);
  const all = (await api("/jobs")).body.map(label);
  assert.equal(all.length, checks.jobs);
  const pageOf = (n) => all.slice(n * checks.page, (n + 1) * checks.page);
  const showing = (want) => until(`rows ${want[0]}…`, async () =>
    JSON.stringify(await firstCells()) === JSON.stringify(want));

  // 1. The newest page: PAGE rows, newest first, "older" offered, "newer" not; the page's
  // icon and style load (no error in the console: a refused script or style would be one).
  await showing(pageOf(0));
  assert.equal(await page.locator("#older").isVisible(), true);
  assert.equal(await page.locator("#newer").isVisible(), false);
  const icon = await page.evaluate(() => fetch("/favicon.ico").then((r) => [r.status, r.headers.get("content-type")]));
  assert.deepEqual(icon, [200, "image/svg+xml"]);
  step("newest page", { rows: await rows.count() });

  // 2. Older, twice, then back a page at a time.
  await page.click("#older"); await showing(pageOf(1));
  assert.equal(await page.locator("#newer").isVisible(), true);
  await page.click("#older"); await showing(pageOf(2));
  assert.equal(await page.locator("#older").isVisible(), false, "a short page is the last");
  await page.click("#newer"); await showing(pageOf(1));
  await page.click("#newer"); await showing(pageOf(0));
  assert.equal(await page.locator("#newer").isVisible(), false);
  step("older pages");

  // 3. A scene submitted through the form (its file chosen in the picker) is queued with
  // the form's priority and listed first, linked to its page.
  const scenePath = path.join(checks.examples, "thesis.ray");
  await page.setInputFiles("#scenefile", scenePath);
  await until("the text area to show the file", async () => (await page.inputValue("#scene")) === checks.scene);
  await page.fill("#tile", String(checks.tile));
  await page.fill("#priority", "7");
  await page.click("button[type=submit]");
  const queued = await until("the queued message", async () =>
    (await page.textContent("#msg")).match(/^Job (\S+) queued: (\d+) tiles\.$/));
  assert.equal(await page.getAttribute("#msg", "class"), "msg ok");
  const [, id, tiles] = queued;
  assert.equal(Number(tiles), checks.tiles);
  const job = (await api("/jobs/" + id)).body;
  assert.equal(job.priority, 7, "the form's priority is the job's");
  assert.equal(job.name, "thesis.ray", "the file names the job");
  await until("the new job first", async () => (await firstCells())[0] === `thesis.ray (${id})`);
  assert.equal(await page.getAttribute(`#jobs > tr[data-id="${id}"] a.job-link`, "href"), `/jobs/${id}`);
  await page.fill("#priority", "");
  step("submitted", { id });

  // 4. A bad scene shows the service's error with its line and column.
  await page.setInputFiles("#scenefile", []);
  await page.fill("#scene", checks.bad_scene);
  await page.click("button[type=submit]");
  const refused = await until("the refusal", async () => {
    const t = await page.textContent("#msg");
    return t.startsWith("line ") ? t : null;
  });
  assert.equal(await page.getAttribute("#msg", "class"), "msg err");
  assert.ok(refused.startsWith(`line ${checks.bad_line}, column ${checks.bad_column}: `), refused);
  step("refused", { message: refused });

  // 5. Cancelling a queued job asks nothing and replaces the message under the form; the
  // same button clicked again deletes nothing. Deleting the cancelled job asks, without
  // mentioning an image, and "no" keeps it.
  const asked = [];
  let answer = false;
  page.on("dialog", (d) => { asked.push(d.message()); answer ? d.accept() : d.dismiss(); });
  const button = page.locator(`#jobs > tr[data-id="${id}"] button`);
  await button.click();
  await until("the cancel", async () => (await api("/jobs/" + id)).body.state === "cancelled");
  await until("the cancel's message", async () => (await page.textContent("#msg")) === "Job thesis.ray cancelled.");
  assert.equal(asked.length, 0, "a cancel needs no confirmation");
  await until("the delete button", async () => (await button.textContent()) === "delete");
  await button.click();
  await until("the question", async () => asked.length === 1);
  assert.ok(asked[0].includes("thesis.ray") && !/image/i.test(asked[0]), asked[0]);
  assert.equal((await api("/jobs/" + id)).status, 200, "kept when the user says no");
  answer = true;
  await button.click();
  await until("the delete", async () => (await api("/jobs/" + id)).status === 404);
  await showing(pageOf(0));
  step("cancelled and deleted", { id });

  // 6. The job an older page starts after is deleted elsewhere: back to the newest page.
  await page.click("#older"); await showing(pageOf(1));
  const anchorId = (await api("/jobs")).body.find((j) => label(j) === all[checks.page - 1]).id;
  assert.equal((await api("/jobs/" + anchorId, { method: "DELETE" })).status, 200);
  assert.equal((await api("/jobs/" + anchorId + "?purge=true", { method: "DELETE" })).status, 204);
  await until("the newest page again", async () => (await firstCells())[0] === all[0]
    && !(await page.locator("#newer").isVisible()));
  step("anchor gone");

  // 7. A scene file and its textures through the pickers: each texture goes under the name
  // the scene gives it.
  const read = (...p) => fs.readFileSync(path.join(checks.examples, ...p));
  await page.setInputFiles("#scenefile", path.join(checks.examples, "textures.ray"));
  await until("the scene text", async () => (await page.inputValue("#scene")) === read("textures.ray").toString("utf8"));
  const textures = ["globe.png", "tile.ppm"];
  await page.setInputFiles("#assets", textures.map((n) => path.join(checks.examples, "textures", n)));
  await page.fill("#tile", "");
  await page.click("button[type=submit]");
  const withTextures = await until("the textured job", async () =>
    (await page.textContent("#msg")).match(/^Job (\S+) queued: \d+ tiles\.$/));
  const textured = withTextures[1];
  const spec = (await api("/worker/jobs/" + textured)).body;
  assert.deepEqual(spec.assets.sort(), textures.map((n) => "textures/" + n));
  for (const n of textures) {
    const r = await fetch(`${base}/worker/jobs/${textured}/assets/${encodeURIComponent("textures/" + n)}`);
    assert.ok(Buffer.from(await r.arrayBuffer()).equals(read("textures", n)), `bytes of ${n}`);
  }
  step("textures", { id: textured });

  // 8. A chosen scene file, unedited, goes as its own bytes: one that is not UTF-8 is
  // refused as such, in one error, and nothing is queued.
  await page.setInputFiles("#assets", []);
  const newest = async () => (await api("/jobs?limit=1")).body[0].id;
  const latin1 = Buffer.concat([Buffer.from("# caf\xe9, Latin-1\n", "latin1"), Buffer.from(checks.scene)]);
  for (const [buffer, name, byte] of [[latin1, "latin1.ray", "0xe9"], [read("textures", "globe.png"), "globe.png", "0x89"]]) {
    const shown = await page.inputValue("#scene");
    await page.setInputFiles("#scenefile", { name, mimeType: "application/octet-stream", buffer });
    await until("the file loaded", async () => (await page.inputValue("#scene")) !== shown);
    await page.click("button[type=submit]");
    const m = await until(`the refusal of ${name}`, async () => {
      const t = await page.textContent("#msg");
      return t.includes("not UTF-8") ? t : null;
    });
    assert.ok(m.includes(`not UTF-8 text (byte ${byte})`) && m.split("\n").length === 1, m);
    assert.equal(await newest(), textured, `nothing queued for ${name}`);
  }
  step("scene file as bytes");

  // 9. A chosen file whose text was edited goes as the edited text, still named by the file.
  await page.setInputFiles("#scenefile", scenePath);
  await until("the scene text", async () => (await page.inputValue("#scene")) === checks.scene);
  await page.fill("#scene", checks.scene.replace("width = 640", "width = 320"));
  await page.click("button[type=submit]");
  const edited = await until("the edited job", async () =>
    (await page.textContent("#msg")).match(/^Job (\S+) queued: \d+ tiles\.$/));
  const editedJob = (await api("/jobs/" + edited[1])).body;
  assert.equal(editedJob.width, 320);
  assert.equal(editedJob.name, "thesis.ray");
  step("edited scene", { id: edited[1] });

  // 10. A list refresh that fails (no answer; an error answer) keeps the rows, under a
  // notice; the next one that works takes the notice away.
  await until("the list", async () => (await firstCells())[0] === `thesis.ray (${edited[1]})`);
  const kept = await firstCells();
  const listing = (url) => new URL(url).pathname === "/jobs";
  for (const [fault, why] of [
    [(route) => route.abort("failed"), "could not reach the service"],
    [(route) => route.fulfill({ status: 503, contentType: "application/json", body: JSON.stringify({ error: "database is locked" }) }), "database is locked"],
  ]) {
    await page.route(listing, fault);
    const notice = await until(`a notice for ${why}`, async () => {
      const visible = await page.locator("#listmsg").isVisible();
      const text = visible ? await page.textContent("#listmsg") : "";
      return text.includes(why) ? text : null;
    });
    assert.ok(notice.startsWith("Could not load the job list") && notice.includes(why), notice);
    assert.deepEqual(await firstCells(), kept, "the rows are kept");
    await page.unroute(listing);
  }
  await until("the notice to go", async () => !(await page.locator("#listmsg").isVisible()));
  step("list notice");

  // 11. At a phone's width (390 px) nothing runs off the side, and every row's button is
  // on screen.
  await page.setViewportSize({ width: 390, height: 844 });
  await until("the narrow layout", async () => !(await overflows(page)));
  for (const box of await page.locator("#jobs button").evaluateAll((bs) => bs.slice(0, 5).map((b) => {
    const r = b.getBoundingClientRect(); return [r.left, r.right];
  }))) {
    assert.ok(box[0] >= 0 && box[1] <= 390, `a button at ${box}`);
  }
  step("narrow");
  // The failures step 10 made on purpose are the only ones.
  const unexpected = page.errors.filter((e) => !/net::ERR_FAILED|status of 503/.test(e));
  assert.deepEqual(unexpected, [], "no error on the page");
  await b.close();
});
