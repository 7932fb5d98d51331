// The service's web page, run under Node against a real service with no submit token and the
// default body limit, in the stand-in browser of `harness.js`. Driven by `tests/tests/page.rs`;
// it prints one line of JSON per step, and fails (exit 1) on the first assertion that does
// not hold.
//
// Usage: node page.js SERVICE_URL CHECKS_JSON

"use strict";
const assert = require("node:assert/strict");
const fs = require("node:fs");
const path = require("node:path");
const { File } = require("node:buffer");
const { openPage, settle, api: request, step, run: runMain } = require("./harness.js");

const [base, checksJson] = process.argv.slice(2);
const checks = JSON.parse(checksJson);

async function main() {
  const page = await openPage(base);
  const { elements, confirmed } = page;
  const run = page.run;
  const api = (p, options) => request(base, p, options);

  const rows = () => elements.jobs.children;
  // The job id or name a row starts with (its first cell).
  const firstCells = () => rows().map((tr) => tr.children[0].text);

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
  elements.priority.value = "7";
  await page.submit();
  elements.priority.value = "";
  const queued = elements.msg.textContent.match(/^Job (\S+) queued: (\d+) tiles\.$/);
  assert.ok(queued, `submission message: ${elements.msg.textContent}`);
  assert.equal(elements.msg.className, "ok");
  const [, id, tiles] = queued;
  assert.equal(Number(tiles), checks.tiles, "tiles of the submitted scene");
  const job = await api("/jobs/" + id);
  assert.equal(job.status, 200);
  assert.equal(job.body.tiles_total, checks.tiles);
  assert.equal(job.body.priority, 7, "the form's priority is the job's");
  assert.equal(firstCells()[0], id, "the new job heads the list");
  step("submitted", { id, tiles: Number(tiles) });

  // 4. A bad scene shows the service's error with its line and column.
  elements.scene.value = checks.bad_scene;
  await page.submit();
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
  page.confirmAnswer = false;
  button().onclick();
  await settle();
  assert.equal(confirmed.length, 1);
  assert.ok(confirmed[0].includes(id), confirmed[0]);
  // A cancelled job has no image to delete, and the question does not say it has.
  assert.ok(!/image/i.test(confirmed[0]), `asked: ${confirmed[0]}`);
  assert.equal((await api("/jobs/" + id)).status, 200, "kept when the user says no");
  page.confirmAnswer = true;
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
  await elements.scenefile.fire("change");
  assert.equal(elements.scene.value, read("textures.ray").toString("utf8"));
  const textures = ["globe.png", "tile.ppm"];
  elements.assets.files = textures.map((n) => new File([read("textures", n)], n));
  elements.tile.value = "";
  await page.submit();
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

  // 8. A chosen scene file, unedited, goes as its own bytes, so that the service checks
  // them: one that is not UTF-8 (Latin-1 here) is refused as such, as curl's upload would be,
  // not sent as its decoded text with U+FFFD in it; so is a PNG chosen by mistake, in one
  // error rather than a hundred parse errors. Nothing is queued.
  elements.assets.files = [];
  const newest = async () => (await api("/jobs?limit=1")).body[0].id;
  const latin1 = Buffer.concat([Buffer.from("# caf\xe9, Latin-1\n", "latin1"), Buffer.from(checks.scene)]);
  for (const [bytes, name, byte] of [
    [latin1, "latin1.ray", "0xe9"],
    [read("textures", "globe.png"), "globe.png", "0x89"],
  ]) {
    elements.scenefile.files = [new File([bytes], name)];
    await elements.scenefile.fire("change");
    await page.submit();
    assert.equal(elements.msg.className, "err", `${name}: ${elements.msg.textContent}`);
    assert.ok(
      elements.msg.textContent.includes(`not UTF-8 text (byte ${byte})`),
      `${name}: ${elements.msg.textContent}`,
    );
    assert.equal(elements.msg.textContent.split("\n").length, 1, elements.msg.textContent);
    assert.equal(await newest(), textured, `nothing queued for ${name}`);
  }
  step("scene file as bytes", { message: elements.msg.textContent });

  // 9. A chosen file whose text was edited after loading goes as the edited text, still named
  // by the file.
  elements.scenefile.files = [new File([checks.scene], "thesis.ray")];
  await elements.scenefile.fire("change");
  assert.equal(elements.scene.value, checks.scene);
  elements.scene.value = checks.scene.replace("width = 640", "width = 320");
  await page.submit();
  const edited = elements.msg.textContent.match(/^Job (\S+) queued: \d+ tiles\.$/);
  assert.ok(edited, `submission message: ${elements.msg.textContent}`);
  const editedJob = (await api("/jobs/" + edited[1])).body;
  assert.equal(editedJob.width, 320, "the edited width");
  assert.equal(editedJob.name, "thesis.ray");
  step("edited scene", { id: edited[1] });

  // 10. A list refresh that fails (no answer; an error answer) keeps the rows drawn, under a
  // notice; the next one that works takes the notice away.
  const before = firstCells();
  assert.equal(elements.listmsg.hidden, true, "no notice while the list loads");
  const listing = (url, options) => url.startsWith("/jobs?") && (options.method || "GET") === "GET";
  const faults = [
    [() => new TypeError("fetch failed"), "fetch failed"],
    [() => ({ status: 503, statusText: "Service Unavailable", body: { error: "database is locked" } }), "database is locked"],
  ];
  for (const [fault, why] of faults) {
    page.fault = (url, options) => (listing(url, options) ? fault() : undefined);
    run("refresh()");
    await settle();
    assert.equal(elements.listmsg.hidden, false, `a notice for ${why}`);
    assert.ok(elements.listmsg.text.startsWith("Could not load the job list"), elements.listmsg.text);
    assert.ok(elements.listmsg.text.includes(why), elements.listmsg.text);
    assert.deepEqual(firstCells(), before, "the rows are kept");
  }
  page.fault = null;
  run("refresh()");
  await settle();
  assert.equal(elements.listmsg.hidden, true, "the notice goes once the list loads");
  assert.equal(elements.listmsg.text, "");
  assert.deepEqual(firstCells(), before);
  step("list notice", {});
}

runMain(main);
