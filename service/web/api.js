// The API page (`/api`): the service's OpenAPI document, read from `/openapi.json` and
// written out for people: each route with its parameters, body and answers, then the
// schemas they name.
"use strict";

const text = (tag, content, cls) => {
  const el = document.createElement(tag);
  el.textContent = content;
  if (cls) el.className = cls;
  return el;
};

// A schema in a few words: its `$ref`'s name, an array of something, or its type.
function typeOf(s) {
  if (!s) return "";
  if (s.$ref) return s.$ref.split("/").pop();
  if (s.allOf) return s.allOf.map(typeOf).join(" + ");
  if (s.oneOf) return s.oneOf.map(typeOf).join(" | ");
  if (s.type === "array" || (Array.isArray(s.type) && s.type.includes("array"))) return `[${typeOf(s.items)}]`;
  const type = Array.isArray(s.type) ? s.type.filter((t) => t !== "null").join(" | ") : (s.type || "any");
  const range = [];
  if (s.minimum != null) range.push(`≥ ${s.minimum}`);
  if (s.maximum != null) range.push(`≤ ${s.maximum}`);
  if (s.enum) range.push(s.enum.join(" | "));
  return range.length ? `${type} (${range.join(", ")})` : type;
}

function operation(path, method, op) {
  const box = document.createElement("section");
  box.className = "op";
  box.id = `${method}-${path}`;
  const h = document.createElement("h3");
  h.append(text("span", method.toUpperCase(), "method"), path);
  box.append(h);
  if (op.description || op.summary) box.append(text("p", op.description || op.summary));
  const params = op.parameters || [];
  if (params.length) {
    const t = document.createElement("table");
    t.className = "cards";
    t.innerHTML = "<thead><tr><th>Parameter</th><th>In</th><th>Type</th><th>Meaning</th></tr></thead>";
    const body = document.createElement("tbody");
    for (const p of params) {
      const tr = document.createElement("tr");
      tr.append(cell(p.name + (p.required ? "" : " (optional)"), "Parameter"), cell(p.in, "In"),
        cell(typeOf(p.schema), "Type"), cell(p.description || "", "Meaning"));
      body.append(tr);
    }
    t.append(body);
    box.append(t);
  }
  if (op.requestBody) {
    const kinds = Object.entries(op.requestBody.content || {}).map(([k, c]) => `${k}: ${typeOf(c.schema)}`);
    box.append(text("p", `Body: ${op.requestBody.description || ""}\n${kinds.join("\n")}`.trim()));
  }
  const t = document.createElement("table");
  t.className = "cards";
  t.innerHTML = "<thead><tr><th>Status</th><th>Answer</th><th>Body</th></tr></thead>";
  const body = document.createElement("tbody");
  for (const [status, r] of Object.entries(op.responses || {})) {
    const kinds = Object.entries(r.content || {}).map(([k, c]) => `${k}: ${typeOf(c.schema)}`);
    const tr = document.createElement("tr");
    tr.append(cell(status, "Status"), cell(r.description || "", "Answer"), cell(kinds.join("; ") || "–", "Body"));
    body.append(tr);
  }
  t.append(body);
  box.append(t);
  return box;
}

function schema(name, s) {
  const box = document.createElement("section");
  box.className = "op";
  box.id = `schema-${name}`;
  box.append(text("h3", name));
  if (s.description) box.append(text("p", s.description));
  const parts = s.allOf ? s.allOf : [s];
  const rows = [];
  for (const part of parts) {
    if (part.$ref) { rows.push([`(everything in ${typeOf(part)})`, "", ""]); continue; }
    const required = new Set(part.required || []);
    for (const [field, f] of Object.entries(part.properties || {})) {
      rows.push([field + (required.has(field) ? "" : " (optional)"), typeOf(f), f.description || ""]);
    }
    if (part.enum) rows.push(["(one of)", part.enum.join(", "), ""]);
  }
  if (rows.length) {
    const t = document.createElement("table");
    t.className = "cards";
    t.innerHTML = "<thead><tr><th>Field</th><th>Type</th><th>Meaning</th></tr></thead>";
    const body = document.createElement("tbody");
    for (const [f, ty, m] of rows) {
      const tr = document.createElement("tr");
      tr.append(cell(f, "Field"), cell(ty, "Type"), cell(m, "Meaning"));
      body.append(tr);
    }
    t.append(body);
    box.append(t);
  }
  return box;
}

async function load() {
  let doc;
  try { doc = await api("/openapi.json"); } catch (e) { $("ops").textContent = `Could not read the document: ${e.message}`; return; }
  $("title").textContent = `${doc.info.title} ${doc.info.version}: the HTTP API (OpenAPI ${doc.openapi})`;
  $("intro").textContent = doc.info.description || "";
  $("ops").replaceChildren();
  for (const [path, item] of Object.entries(doc.paths)) {
    for (const method of ["get", "post", "put", "patch", "delete"]) {
      if (item[method]) $("ops").append(operation(path, method, item[method]));
    }
  }
  for (const [name, s] of Object.entries((doc.components || {}).schemas || {})) $("schemas").append(schema(name, s));
}
load();
