// What every page of Tessera's shares: finding elements, the tokens a service may ask for,
// talking to the JSON routes, and writing times and sizes for people.
"use strict";

const $ = (id) => document.getElementById(id);

// The token a service started with `--submit-token` (or a read token) asks for. Kept in the
// browser's storage so that it is typed once, and in a cookie for what a page loads without
// headers (images, the event stream), which the service reads for reads only.
const tokenKey = "tessera-submit-token";
const token = {
  get() { return localStorage.getItem(tokenKey) || ""; },
  set(value) {
    const t = (value || "").trim();
    if (t) {
      localStorage.setItem(tokenKey, t);
      document.cookie = `tessera_token=${encodeURIComponent(t)}; path=/; SameSite=Strict`;
    } else {
      localStorage.removeItem(tokenKey);
      document.cookie = "tessera_token=; path=/; SameSite=Strict; max-age=0";
    }
  },
  headers() {
    const t = this.get();
    return t ? { Authorization: "Bearer " + t } : {};
  },
};

// Binds a token field: it shows the saved token, saves what is typed, and an emptied field
// forgets it.
function bindToken(input) {
  input.value = token.get();
  input.addEventListener("input", () => token.set(input.value));
  input.addEventListener("change", () => token.set(input.value));
}

// The service's error from an answer that is not ok: its JSON `error`, or the status.
async function answerError(r) {
  const body = await r.json().catch(() => ({}));
  return body.error || r.statusText || `HTTP ${r.status}`;
}

// A request to a JSON route with the saved token: the answer's JSON (null for 204), or an
// Error whose message is the service's own (or says it could not be reached).
async function api(path, options = {}) {
  const headers = { ...token.headers(), ...(options.headers || {}) };
  let r;
  try {
    r = await fetch(path, { ...options, headers });
  } catch (e) {
    throw new Error(`could not reach the service (${e.message || e})`);
  }
  if (!r.ok) {
    const err = new Error(await answerError(r));
    err.status = r.status;
    throw err;
  }
  return r.status === 204 ? null : r.json();
}

function bytes(n) {
  return n >= 1 << 20 ? `${n} bytes (${(n / (1 << 20)).toFixed(1)} MiB)` : `${n} bytes`;
}

// A duration in milliseconds as "1 h 02 min", "3 min 05 s" or "12.3 s".
function duration(ms) {
  if (!(ms >= 0)) return "–";
  const s = ms / 1000;
  if (s < 60) return `${s.toFixed(s < 10 ? 1 : 0)} s`;
  const m = Math.floor(s / 60);
  if (m < 60) return `${m} min ${String(Math.floor(s % 60)).padStart(2, "0")} s`;
  return `${Math.floor(m / 60)} h ${String(m % 60).padStart(2, "0")} min`;
}

// A time (ms since the epoch) as the browser's local date and time; today's without the date.
function when(ms) {
  if (ms == null) return "–";
  const d = new Date(ms);
  const today = new Date().toDateString() === d.toDateString();
  return today ? d.toLocaleTimeString() : d.toLocaleString();
}

// How long a job has run (or ran): from its first claim to its end or now.
function elapsed(job, now = Date.now()) {
  if (job.started_at == null) return null;
  return (job.finished_at ?? now) - job.started_at;
}

// The time left at the job's rate so far, once a tile is in and while it runs.
function eta(job, now = Date.now()) {
  const spent = elapsed(job, now);
  if (spent == null || job.finished_at != null || !job.tiles_done) return null;
  return (spent / job.tiles_done) * (job.tiles_total - job.tiles_done);
}

// The sampler a job asked for, with its settings, or the scene's.
function samplerText(job) {
  if (!job.sampler && job.samples == null && job.threshold == null) return "the scene's";
  let t = job.sampler || "the scene's";
  if (job.samples != null) t += ` ${job.samples}×${job.samples}`;
  if (job.threshold != null) t += `, threshold ${job.threshold}`;
  return t;
}

function cell(text, label) {
  const td = document.createElement("td");
  td.textContent = text;
  if (label) td.dataset.label = label;
  return td;
}

function isActive(job) { return job.state === "queued" || job.state === "running"; }
