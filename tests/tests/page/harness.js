// The stand-in browser the page scripts (`page.js`, `guarded.js`) run the web page in: the
// page's script, taken from the page the service serves, in a `vm` context with a small
// stand-in for the DOM (elements are plain objects that keep their children, text and
// handlers), `localStorage`, `confirm`, and `fetch` on the real service, every request
// recorded and any of them replaceable by a fault (a network error, an error answer).
//
// What it does not cover: layout, CSS, the browser's own form controls, file pickers.

"use strict";
const vm = require("node:vm");

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
  // Runs this element's handlers for `event` (none is no error), as the browser would.
  async fire(event) {
    for (const f of this.listeners[event] || []) await f();
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

// An answer as the page's `fetch` gives it.
function answer(status, statusText, text) {
  return {
    ok: status >= 200 && status < 300,
    status,
    statusText,
    json: async () => JSON.parse(text),
  };
}

// Opens the page served at `base`, with `storage` (a Map) as its `localStorage`: pass the
// one of an earlier page to reload it. Returns what a test drives it by, once it has drawn.
async function openPage(base, { storage = new Map() } = {}) {
  const html = await (await fetch(base + "/")).text();
  const script = html.match(/<script>([\s\S]*)<\/script>/)[1];
  const elements = {};
  for (const [, id] of html.matchAll(/\bid="([^"]+)"/g)) elements[id] = new Element("?", id);
  // The page's `hidden` attributes, as the browser would have them before the script runs.
  for (const [, id] of html.matchAll(/\bid="([^"]+)"[^>]*\bhidden\b/g)) elements[id].hidden = true;
  const page = {
    elements,
    storage,
    // The answer `confirm` gives, and every question it was asked.
    confirmAnswer: true,
    confirmed: [],
    // Every request the page made, `{ method, url }`, faulted ones included.
    requests: [],
    // `(url, options)` => undefined to let the request through, or what stands in for it:
    // an error to throw (a network error) or `{ status, statusText, body }` to answer.
    fault: null,
  };
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
      removeItem: (k) => storage.delete(k),
    },
    confirm: (question) => {
      page.confirmed.push(question);
      return page.confirmAnswer;
    },
    // The timer is not run: each step refreshes explicitly, so that what it sees is what
    // that step did.
    setInterval: () => 0,
    URLSearchParams,
    FormData,
    Blob,
    fetch: (url, options = {}) => {
      page.requests.push({ method: options.method || "GET", url });
      const fault = page.fault && page.fault(url, options);
      if (fault instanceof Error) return track(Promise.reject(fault));
      if (fault) {
        const text = JSON.stringify(fault.body ?? {});
        return track(Promise.resolve(answer(fault.status, fault.statusText, text)));
      }
      return track(
        fetch(url.startsWith("/") ? base + url : url, options).then(async (r) =>
          answer(r.status, r.statusText, await r.text()),
        ),
      );
    },
  };
  vm.createContext(context);
  vm.runInContext(script, context);
  page.run = (code) => vm.runInContext(code, context);
  // Submits the form, and waits for what follows.
  page.submit = async () => {
    await elements.submit.listeners.submit[0]({ preventDefault() {} });
    await settle();
  };
  // The POST requests the page sent.
  page.posts = () => page.requests.filter((r) => r.method === "POST");
  await settle();
  return page;
}

// A request straight to the service, not through the page: its status and JSON body.
async function api(base, path, options) {
  const r = await fetch(base + path, options);
  const text = await r.text();
  return { status: r.status, body: text ? JSON.parse(text) : null };
}

// One line of JSON naming a step that passed: `page.rs` checks every step ran.
function step(name, facts) {
  console.log(JSON.stringify({ step: name, ...facts }));
}

// Runs a page script's `main`, failing the process (exit 1) on the first assertion that
// does not hold, or on an unhandled rejection (Node's default).
function run(main) {
  main().catch((e) => {
    console.error(e && e.stack ? e.stack : e);
    process.exit(1);
  });
}

module.exports = { openPage, settle, api, step, run };
