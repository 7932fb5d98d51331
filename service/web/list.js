// The job list (`GET /`): submit a scene, see jobs a page at a time with their progress,
// open a job's page, cancel or delete jobs, and see the workers.
"use strict";

// The service's --max-body-bytes (written into the page as it is served): a larger upload
// is answered 413 before it is read and the connection closed, which fetch reports as a
// network error, so the page refuses it itself. NaN (no check) if the page was not served.
const maxBody = Number(document.querySelector('meta[name="tessera-max-body-bytes"]').content);
// What the multipart framing adds per part (boundary and headers), besides the file's name.
const partBytes = 256;

bindToken($("token"));

// The message under the form. A notice says what the last action did; the next action
// replaces it, so that "queued" does not outlive the job's cancel.
function say(kind, text) { const m = $("msg"); m.className = "msg " + kind; m.textContent = text; }

// The chosen scene file and the text area as loaded from it: while the text is unedited the
// file's own bytes are sent, so that the service checks them (a file that is not UTF-8 text
// is refused as such, not sent as its decoded text with U+FFFD in it).
let loaded = null;
$("scenefile").addEventListener("change", async () => {
  const f = $("scenefile").files[0];
  if (!f) return;
  const text = await f.text();
  if ($("scenefile").files[0] !== f) return; // another file was chosen meanwhile
  $("scene").value = text;
  loaded = { file: f, text: $("scene").value };
});

$("submit").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const text = $("scene").value;
  if (!text.trim()) { say("err", "Choose or paste a scene first."); return; }
  const params = new URLSearchParams();
  for (const k of ["tile", "sampler", "samples", "priority"]) if ($(k).value) params.set(k, $(k).value);
  const f = $("scenefile").files[0];
  if (f) params.set("name", f.name);
  const form = new FormData();
  // A chosen file's name names the job; pasted text goes as a plain field, naming nothing.
  // An unedited file goes as itself, an edited one as the text.
  const scene = f && loaded && loaded.file === f && loaded.text === text
    ? f : new Blob([text], { type: "text/plain" });
  if (f) form.append("scene", scene, f.name);
  else form.append("scene", text);
  // Each texture by its file name: the service gives it to the scene's texture of that name
  // (`textures/globe.png` gets `globe.png`).
  const assets = [...$("assets").files];
  for (const file of assets) form.append("asset", file, file.name);
  // The body's size, the framing counted generously: one over the limit is refused here.
  // Pasted text goes as a string field, whose line breaks a form sends as CRLF: one byte
  // more a line than the text holds.
  let size = scene.size + partBytes + (f ? new Blob([f.name]).size : (text.match(/\n/g) || []).length);
  for (const file of assets) size += file.size + partBytes + new Blob([file.name]).size;
  if (size > maxBody) {
    say("err", `${assets.length ? "The scene and its textures come" : "The scene comes"} ` +
      `to about ${bytes(size)} as a form, over this service's limit of ${bytes(maxBody)} ` +
      "(set by its --max-body-bytes): send less, or start the service with a larger --max-body-bytes.");
    return;
  }
  say("", "Submitting…");
  let r;
  try {
    r = await fetch("/jobs?" + params, { method: "POST", body: form, headers: token.headers() });
  } catch (e) { say("err", "Could not reach the service: " + e); return; }
  const body = await r.json().catch(() => ({}));
  if (!r.ok) {
    say("err", body.errors
      ? body.errors.map((e) => `line ${e.line}, column ${e.column}: ${e.message}`).join("\n")
      : (body.error || r.statusText));
    return;
  }
  say("ok", `Job ${body.id} queued: ${body.tiles_total} tiles.`);
  refresh();
});

// A job still to render is cancelled at once; a finished one is deleted, image and all,
// so that asks first. The two are different requests: a cancel that reaches a job that
// has just finished leaves it (and its image) as it is. Only a done job has an image to
// mention. Whatever the outcome, it replaces the message under the form.
async function cancelOrDelete(j) {
  const label = j.name || j.id;
  const active = isActive(j);
  const question = j.state === "done" ? `Delete job ${label} and its image?` : `Delete job ${label}?`;
  if (!active && !confirm(question)) return;
  const url = "/jobs/" + j.id + (active ? "" : "?purge=true");
  try {
    await api(url, { method: "DELETE" });
    say("", active ? `Job ${label} cancelled.` : `Job ${label} deleted.`);
  } catch (e) {
    say("err", `Could not ${active ? "cancel" : "delete"} job ${label}: ${e.message}`);
  }
  refresh();
}

// A list that could not be loaded stays as it was, under a notice.
function listNotice(text) { $("listmsg").textContent = text; $("listmsg").hidden = !text; }

// The list shows PAGE jobs at a time, newest first. `before` is the job the page shown
// starts after ("" for the newest page) and `anchors` the `before` of each page above it,
// for the way back.
const PAGE = 50;
let before = "";
const anchors = [];
let shown = 0;

function jobRow(j) {
  const tr = document.createElement("tr");
  tr.dataset.id = j.id;
  const name = document.createElement("td");
  name.dataset.label = "Job";
  const a = document.createElement("a");
  a.href = j.url; a.textContent = j.name || j.id; a.className = "job-link";
  name.append(a);
  if (j.name) name.append(` (${j.id})`);
  tr.append(name);
  const why = j.error || j.paused;
  const st = cell(j.state + (why ? ": " + why : ""), "State");
  st.className = "state state-" + j.state; tr.append(st);
  tr.append(cell(`${j.width}×${j.height}`, "Size"));
  tr.append(cell(samplerText(j), "Sampler"));
  tr.append(cell(String(j.priority), "Priority"));
  tr.append(cell(when(j.created_at), "Submitted"));
  const spent = elapsed(j);
  tr.append(cell(spent == null ? "–" : duration(spent), "Duration"));
  const p = document.createElement("td"); p.dataset.label = "Progress";
  const bar = document.createElement("progress");
  bar.max = j.tiles_total; bar.value = j.tiles_done;
  p.append(bar, ` ${j.tiles_done}/${j.tiles_total}`); tr.append(p);
  const img = document.createElement("td"); img.dataset.label = "Image";
  if (j.state === "running" && j.tiles_done > 0) {
    // As far as it is rendered: the browser asks again with the preview's ETag.
    const link = document.createElement("a"); link.href = j.url;
    const i = document.createElement("img"); i.className = "thumb"; i.src = j.preview_url; i.alt = "the image so far";
    link.append(i); img.append(link);
  } else if (j.state === "done") {
    const link = document.createElement("a"); link.href = j.image_url; link.target = "_blank";
    const i = document.createElement("img"); i.className = "thumb"; i.src = j.image_url; i.alt = "rendered image";
    link.append(i); img.append(link);
    const dl = document.createElement("a"); dl.href = j.image_url; dl.download = (j.name || j.id).replace(/\.ray$/, "") + ".png"; dl.textContent = "download";
    img.append(dl);
  }
  tr.append(img);
  const act = document.createElement("td");
  const b = document.createElement("button");
  b.className = "small";
  b.textContent = isActive(j) ? "cancel" : "delete";
  b.onclick = () => cancelOrDelete(j); act.append(b); tr.append(act);
  return tr;
}

async function refresh() {
  // Refreshes overlap (the timer, a click); only the latest one may draw.
  const me = ++shown;
  const query = new URLSearchParams({ limit: PAGE });
  if (before) query.set("before", before);
  let jobs;
  try {
    jobs = await api("/jobs?" + query);
  } catch (e) {
    if (me !== shown) return;
    if (e.status === 404 && before) {
      // The job this page started after is gone: back to the newest.
      before = ""; anchors.length = 0;
      return refresh();
    }
    listNotice(`Could not load the job list: ${e.message}. The list below may be out of date.`);
    return;
  }
  if (me !== shown) return;
  listNotice("");
  const body = $("jobs");
  body.replaceChildren();
  $("newer").hidden = !before;
  $("older").hidden = jobs.length < PAGE;
  $("older").onclick = () => { anchors.push(before); before = jobs[jobs.length - 1].id; refresh(); };
  if (!jobs.length) {
    const tr = document.createElement("tr");
    tr.append(cell(before ? "No older jobs." : "No jobs yet."));
    body.append(tr);
  }
  for (const j of jobs) body.append(jobRow(j));
}

// The workers heard from lately: what each does now, and what it has done.
async function refreshWorkers() {
  let workers;
  try { workers = await api("/workers"); } catch { return; }
  const body = $("workers");
  body.replaceChildren();
  if (!workers.length) {
    const tr = document.createElement("tr");
    tr.append(cell("No worker heard from in the last ten minutes."));
    body.append(tr);
  }
  for (const w of workers) body.append(workerRow(w));
}

function workerRow(w) {
  const tr = document.createElement("tr");
  tr.dataset.name = w.name;
  tr.append(cell(w.name, "Worker"));
  const state = w.state || "";
  const st = cell(state === "gone" && w.left_cleanly ? "gone (stopped)" : state, "State");
  st.className = "state state-" + state; tr.append(st);
  const doing = document.createElement("td"); doing.dataset.label = "Rendering";
  for (const t of w.tiles || []) {
    const a = document.createElement("a");
    a.href = "/jobs/" + t.job; a.textContent = `tile ${t.idx} of ${t.job}`;
    doing.append(a, " ");
  }
  tr.append(doing);
  tr.append(cell(w.threads == null ? "–" : String(w.threads), "Threads"));
  tr.append(cell(w.rays_per_second == null ? "–" : Math.round(w.rays_per_second).toLocaleString(), "Rays/s"));
  tr.append(cell(String(w.tiles_done), "Tiles done"));
  tr.append(cell(when(w.last_seen), "Last heard from"));
  return tr;
}

$("newer").onclick = () => { before = anchors.pop() || ""; refresh(); };
function refreshAll() { refresh(); refreshWorkers(); }
refreshAll();
// Every second while the page is in view; at once when it comes back into view.
setInterval(() => { if (!document.hidden) refreshAll(); }, 1000);
document.addEventListener("visibilitychange", () => { if (!document.hidden) refreshAll(); });
