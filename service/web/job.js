// A job's page (`/jobs/{id}` in a browser): its facts, the image as far as it is rendered
// with a map of its tiles over it, which worker holds which tile, failures, the scene, and
// the actions (cancel, retry, delete, priority). Kept current by the job's server-sent
// events (`/jobs/{id}/events`), not by polling.
"use strict";

const id = decodeURIComponent(location.pathname.split("/")[2] || "");
const jobPath = "/jobs/" + encodeURIComponent(id);
bindToken($("token"));

let job = null;           // the job as last told
const tiles = new Map();  // idx → tile as last told
const cells = new Map();  // idx → its element on the map
let source = null;        // the event stream, while open

function say(kind, text) { const m = $("msg"); m.className = "msg " + kind; m.textContent = text; }
function notice(text) { $("notice").textContent = text; $("notice").hidden = !text; }

// --- The facts and the actions -------------------------------------------------------------

function drawJob() {
  const j = job;
  document.title = `${j.name || j.id} · Tessera`;
  $("title").textContent = j.name ? `${j.name} (${j.id})` : `Job ${j.id}`;
  const why = j.error || j.paused;
  $("state").textContent = j.state + (why ? ": " + why : "");
  $("state").className = "state state-" + j.state;
  $("bar").max = j.tiles_total; $("bar").value = j.tiles_done;
  $("tiles").textContent = `${j.tiles_done}/${j.tiles_total}`;
  $("size").textContent = `${j.width}×${j.height}`;
  $("tile").textContent = `${j.tile} px`;
  $("sampler").textContent = samplerText(j);
  $("priority").textContent = String(j.priority);
  $("submitted").textContent = when(j.created_at);
  const active = isActive(j);
  $("cancel").hidden = !active;
  $("prioform").hidden = !active;
  if (document.activeElement !== $("newpriority")) $("newpriority").value = String(j.priority);
  $("delete").hidden = active;
  $("retry").hidden = !(j.state === "failed" || j.state === "cancelled");
  $("download").hidden = j.state !== "done";
  if (j.state === "done") {
    $("download").href = j.image_url;
    $("download").download = (j.name || j.id).replace(/\.ray$/, "") + ".png";
  }
  $("stage").style.aspectRatio = `${j.width} / ${j.height}`;
  tick();
}

// Elapsed time and time left, every second while the job runs.
function tick() {
  if (!job) return;
  const spent = elapsed(job);
  $("elapsed").textContent = spent == null ? "not started" : duration(spent);
  const left = eta(job);
  $("eta").textContent = isActive(job) ? (left == null ? "–" : duration(left)) : "–";
}
setInterval(tick, 1000);

async function act(what, request, after) {
  try {
    const answer = await request();
    say("ok", what);
    if (after) after(answer);
  } catch (e) {
    say("err", `${what.replace(/\.$/, "")} failed: ${e.message}`);
  }
}

$("cancel").onclick = () => act("Cancelled.", () => api(jobPath, { method: "DELETE" }));
// The job's events ended with it: they are followed again once it is active.
$("retry").onclick = () => act("Queued again: only the missing tiles render.",
  () => api(jobPath + "/retry", { method: "POST" }), (j) => { job = j; drawJob(); follow(); });
$("delete").onclick = () => {
  const question = job && job.state === "done" ? "Delete this job and its image?" : "Delete this job?";
  if (!confirm(question)) return;
  act("Deleted.", () => api(jobPath + "?purge=true", { method: "DELETE" }), () => { location.href = "/"; });
};
$("prioform").addEventListener("submit", (ev) => {
  ev.preventDefault();
  const priority = Number($("newpriority").value);
  act(`Priority set to ${priority}.`, () => api(jobPath, {
    method: "PATCH",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ priority }),
  }), (j) => { job = j; drawJob(); });
});
$("showmap").onchange = () => $("map").classList.toggle("hidden", !$("showmap").checked);

// --- The tile map and the table of tiles at work -------------------------------------------

function tileText(t) {
  let s = `tile ${t.idx} at ${t.x},${t.y} (${t.w}×${t.h}): ${t.state}`;
  if (t.state === "leased" && t.worker) s += ` by ${t.worker}, attempt ${t.attempts}`;
  if (t.state === "done" && t.worker) s += ` by ${t.worker}`;
  if (t.failures) s += `; ${t.failures} failure${t.failures > 1 ? "s" : ""}${t.error ? ": " + t.error : ""}`;
  return s;
}

function drawTile(t) {
  let el = cells.get(t.idx);
  if (!el) {
    el = document.createElement("div");
    el.style.left = `${(100 * t.x) / job.width}%`;
    el.style.top = `${(100 * t.y) / job.height}%`;
    el.style.width = `${(100 * t.w) / job.width}%`;
    el.style.height = `${(100 * t.h) / job.height}%`;
    el.dataset.idx = t.idx;
    cells.set(t.idx, el);
    $("map").append(el);
  }
  el.className = `tile-${t.state}` + (t.failures && t.state !== "done" ? " tile-failed" : "");
  el.dataset.state = t.state;
  el.dataset.worker = t.state === "leased" ? (t.worker || "") : "";
  el.title = tileText(t);
}

// Tiles at work (leased) and tiles that failed before, by index; at most 200 rows.
let tableDue = false;
function drawTable() {
  tableDue = false;
  const rows = [...tiles.values()].filter((t) => t.state === "leased" || t.failures > 0)
    .sort((a, b) => a.idx - b.idx);
  const body = $("tilerows");
  body.replaceChildren();
  if (!rows.length) {
    const tr = document.createElement("tr");
    tr.append(cell(isActive(job) ? "No tile is being rendered now, and none has failed." : "None."));
    body.append(tr);
  }
  for (const t of rows.slice(0, 200)) {
    const tr = document.createElement("tr");
    tr.dataset.idx = t.idx;
    tr.append(cell(String(t.idx), "Tile"), cell(`${t.x},${t.y} ${t.w}×${t.h}`, "Place"),
      cell(t.state, "State"), cell(t.state === "leased" ? (t.worker || "") : "–", "Worker"),
      cell(String(t.attempts), "Attempts"), cell(String(t.failures), "Failures"),
      cell(t.error || "–", "Last failure"));
    body.append(tr);
  }
  const holders = [...new Set(rows.filter((t) => t.state === "leased").map((t) => t.worker))];
  $("holders").textContent = holders.length ? holders.join(", ") : "none";
}
// Redrawn once per frame however many tiles change in it.
function tableLater() {
  if (!tableDue) { tableDue = true; requestAnimationFrame(drawTable); }
}

// --- The preview ---------------------------------------------------------------------------

// The preview is fetched again at most once a second while tiles arrive; the browser asks
// with the ETag it holds, and the service answers 304 while nothing new is stored.
let previewBusy = false, previewDue = false, previewAt = 0, previewUrl = null;
async function refreshPreview() {
  if (previewBusy) { previewDue = true; return; }
  const wait = previewAt + 1000 - Date.now();
  if (wait > 0) { previewDue = true; setTimeout(refreshPreview, wait); return; }
  previewBusy = true; previewDue = false; previewAt = Date.now();
  try {
    if (job.state === "done") {
      $("preview").src = job.image_url;
    } else {
      const r = await fetch(job.preview_url, { cache: "no-cache", headers: token.headers() });
      if (r.ok) {
        const url = URL.createObjectURL(await r.blob());
        $("preview").src = url;
        if (previewUrl) URL.revokeObjectURL(previewUrl);
        previewUrl = url;
        $("preview").dataset.tilesDone = r.headers.get("ETag") || "";
      }
    }
  } catch { /* the next tile tries again */ }
  previewBusy = false;
  if (previewDue) refreshPreview();
}

// --- The events ----------------------------------------------------------------------------

function follow() {
  if (source) source.close();
  source = new EventSource(jobPath + "/events");
  const data = (ev) => JSON.parse(ev.data);
  source.addEventListener("job", (ev) => {
    const before = job;
    job = data(ev);
    notice("");
    drawJob();
    if (!before || before.tiles_done !== job.tiles_done || before.state !== job.state) refreshPreview();
  });
  source.addEventListener("tiles", (ev) => {
    tiles.clear(); cells.clear(); $("map").replaceChildren();
    for (const t of data(ev)) { tiles.set(t.idx, t); drawTile(t); }
    drawTable();
  });
  source.addEventListener("tile", (ev) => {
    const t = data(ev);
    const before = tiles.get(t.idx);
    tiles.set(t.idx, t); drawTile(t); tableLater();
    if (t.state === "done" && (!before || before.state !== "done")) refreshPreview();
  });
  source.addEventListener("failure", (ev) => {
    const f = data(ev);
    say("err", `Tile ${f.idx} failed (${f.failures} failure${f.failures > 1 ? "s" : ""}): ${f.error || "no reason given"}`);
  });
  source.addEventListener("end", (ev) => {
    job = data(ev); drawJob(); refreshPreview();
    source.close(); source = null;
  });
  source.addEventListener("deleted", () => {
    notice("This job has been deleted.");
    source.close(); source = null;
  });
  source.onerror = async () => {
    // A stream refused at once (no such job, a token needed) is closed for good; say why.
    if (source && source.readyState === EventSource.CLOSED) {
      source = null;
      try { await api(jobPath); } catch (e) { notice(`Could not follow this job: ${e.message}`); }
    }
  };
}

async function loadScene() {
  try {
    const r = await fetch(jobPath + "/scene", { headers: token.headers() });
    $("scene").textContent = r.ok ? await r.text() : `(the scene could not be read: ${await answerError(r)})`;
  } catch (e) { $("scene").textContent = `(the scene could not be read: ${e})`; }
}

follow();
loadScene();
