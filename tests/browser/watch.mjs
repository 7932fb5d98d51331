// Watching a job in Chromium: a scene submitted through the form, its page (at its own
// address), the tile map, the preview filling in while the job runs (its pixels read back),
// which worker holds which tile, the priority changed, cancel, retry (only the missing
// tiles render), delete, the API page, and a phone's width. Against a service with one worker,
// `checks.worker_pid`, which the Rust side started and stopped (SIGSTOP): this script lets
// it run (SIGCONT) and stops it again to hold the job part-way. Run by
// `tests/tests/browser.rs`.
import assert from "node:assert/strict";
import path from "node:path";
import { api, base, browser, checks, openPage, overflows, run, step, until } from "./lib.mjs";

run(async () => {
  const b = await browser();
  const page = await openPage(b);
  await page.goto(base + "/");

  // 1. Submit through the form with the file picker; open the job's page from the list.
  await page.setInputFiles("#scenefile", path.join(checks.examples, "thesis.ray"));
  await until("the scene text", async () => (await page.inputValue("#scene")).length > 0);
  await page.fill("#tile", String(checks.tile));
  await page.selectOption("#sampler", "jitter");
  await page.fill("#samples", String(checks.samples));
  await page.click("button[type=submit]");
  const [, id] = await until("the queued message", async () =>
    (await page.textContent("#msg")).match(/^Job (\S+) queued: (\d+) tiles\.$/));
  await page.click(`#jobs > tr[data-id="${id}"] a.job-link`);
  await page.waitForURL(`${base}/jobs/${id}`);
  step("job page", { url: page.url() });

  // 2. The page says what the job is; its map holds every tile, all queued; the scene is
  // the one submitted.
  const job = (await api("/jobs/" + id)).body;
  await until("the state", async () => (await page.textContent("#state")) === "queued");
  assert.equal(await page.textContent("#size"), `${job.width}×${job.height}`);
  assert.equal(await page.textContent("#sampler"), `jitter ${checks.samples}×${checks.samples}`);
  const cells = page.locator("#map > div");
  await until("the map", async () => (await cells.count()) === job.tiles_total);
  assert.equal(await page.locator('#map > div[data-state="queued"]').count(), job.tiles_total);
  await page.click("#scenebox summary");
  assert.equal(await page.textContent("#scene"), checks.scene);
  step("tile map", { tiles: job.tiles_total });

  // 3. The priority changes from the page; the service has it.
  await page.fill("#newpriority", "42");
  await page.click("#prioform button");
  await until("the new priority", async () => (await page.textContent("#priority")) === "42");
  assert.equal((await api("/jobs/" + id)).body.priority, 42);
  step("priority");

  // 4. The worker runs: tiles are leased by it (the map and the table say so) and stored.
  // Once some are stored, it is stopped again: the job is part-way.
  process.kill(checks.worker_pid, "SIGCONT");
  const leasedBy = await until("a tile held by the worker", async () => {
    const w = await page.locator('#map > div[data-state="leased"]').first().getAttribute("data-worker").catch(() => null);
    return w || null;
  });
  assert.equal(leasedBy, checks.worker_name);
  await until("a stored tile", async () => (await api("/jobs/" + id)).body.tiles_done >= 2);
  process.kill(checks.worker_pid, "SIGSTOP");
  const held = (await api("/jobs/" + id)).body;
  assert.ok(held.tiles_done < held.tiles_total, `part-way: ${held.tiles_done}/${held.tiles_total}`);
  assert.equal(held.state, "running");
  await until("the worker in the table", async () =>
    (await page.locator("#tilerows").textContent()).includes(checks.worker_name));
  assert.equal(await page.textContent("#holders"), checks.worker_name);
  step("leased", { worker: leasedBy, tiles_done: held.tiles_done });

  // 5. The preview shows the stored tiles, and only them: read back from the page's image,
  // the pixels of a stored tile are opaque, those of a queued tile transparent.
  const tiles = (await api(`/jobs/${id}/tiles`)).body;
  const doneTile = tiles.find((t) => t.state === "done");
  const queuedTile = tiles.find((t) => t.state === "queued");
  assert.ok(doneTile && queuedTile, "a stored and a queued tile");
  const alphaAt = (t) => page.evaluate(([x, y]) => {
    const img = document.getElementById("preview");
    if (!img.complete || !img.naturalWidth) return null;
    const c = document.createElement("canvas");
    c.width = img.naturalWidth; c.height = img.naturalHeight;
    const g = c.getContext("2d");
    g.drawImage(img, 0, 0);
    return g.getImageData(x, y, 1, 1).data[3];
  }, [t.x + (t.w >> 1), t.y + (t.h >> 1)]);
  await until("the stored tile in the preview", async () => (await alphaAt(doneTile)) === 255);
  assert.equal(await alphaAt(queuedTile), 0, "a queued tile is transparent");
  assert.equal(await page.locator(`#map > div[data-idx="${doneTile.idx}"]`).getAttribute("data-state"), "done");
  step("preview", { stored: doneTile.idx, queued: queuedTile.idx });

  // 6. At a phone's width nothing runs off the side of the job's page.
  await page.setViewportSize({ width: 390, height: 844 });
  await until("the narrow layout", async () => !(await overflows(page)));
  await page.setViewportSize({ width: 1280, height: 900 });
  step("narrow");

  // 7. Cancel from the page: the state says so, and the actions change.
  await page.click("#cancel");
  await until("cancelled", async () => (await page.textContent("#state")) === "cancelled");
  assert.equal(await page.locator("#delete").isVisible(), true);
  assert.equal(await page.locator("#cancel").isVisible(), false);
  assert.equal(await page.locator("#retry").isVisible(), true);
  const kept = (await api(`/jobs/${id}/tiles`)).body.filter((t) => t.state === "done");
  assert.ok(kept.some((t) => t.idx === doneTile.idx), "the cancelled job keeps its stored tiles");
  process.kill(checks.worker_pid, "SIGCONT");
  step("cancelled", { kept: kept.length });

  // 8. Retry from the page: the job runs again, its stored tiles are not handed out again,
  // and it ends done with its PNG offered.
  await page.click("#retry");
  await until("done after the retry", async () => (await page.textContent("#state")) === "done");
  assert.equal(await page.locator("#retry").isVisible(), false);
  assert.equal(await page.locator("#download").isVisible(), true);
  const after = new Map((await api(`/jobs/${id}/tiles`)).body.map((t) => [t.idx, t]));
  for (const t of kept) {
    assert.equal(after.get(t.idx).attempts, t.attempts, `tile ${t.idx} was handed out again`);
  }
  step("retried");

  // 9. Delete from the page (it asks first) goes back to the list, without the job.
  page.once("dialog", (d) => d.accept());
  await page.click("#delete");
  await page.waitForURL(base + "/");
  assert.equal((await api("/jobs/" + id)).status, 404);
  step("deleted");

  // 10. The API page lists every route of the document.
  await page.goto(base + "/api");
  const doc = (await api("/openapi.json")).body;
  const routes = Object.values(doc.paths).reduce((n, item) => n + Object.keys(item).filter((k) =>
    ["get", "post", "put", "patch", "delete"].includes(k)).length, 0);
  await until("the routes", async () => (await page.locator("section.op h3 .method").count()) === routes);
  assert.ok(await page.locator("#ops").textContent().then((t) => t.includes("/jobs/{id}/preview.png")));
  step("api page", { routes });
  assert.deepEqual(page.errors, [], "no error on the pages");
  await b.close();
});
