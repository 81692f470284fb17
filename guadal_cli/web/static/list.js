// The mission list: newest first, filtered in the page, new runs arrive over the live stream.
"use strict";

const filters = document.getElementById("filters");
const tbody = document.querySelector("#runs tbody");
let runs = [];
let known = null;

// The table and the filters are updated in place, never rebuilt: the stream sends the list
// every time a run moves on, and a link or an open drop-down replaced under the pointer would
// swallow the click.
const rowsById = new Map();

function setText(el, value) {
  const text = String(value ?? "");
  if (el.textContent !== text) el.textContent = text;
}

function fillSelect(name) {
  const select = filters.elements[name];
  const values = [...new Set(runs.map((r) => r[name]).filter((v) => v !== null && v !== undefined))].map(String).sort();
  const offered = [...select.options].slice(1).map((o) => o.value);
  if (offered.join("\n") === values.join("\n")) return;
  const current = select.value;
  select.replaceChildren(new Option("any", ""), ...values.map((v) => new Option(v, v, false, v === current)));
}

function rowFor(r) {
  let tr = rowsById.get(r.id);
  if (!tr) {
    tr = document.createElement("tr");
    tr.dataset.id = r.id;
    tr.innerHTML = `<td data-f="started"></td><td><a></a></td><td data-f="map"></td><td data-f="algorithm"></td>
      <td data-f="level"></td><td class="num" data-f="vehicles"></td><td class="num" data-f="steps"></td>
      <td><span class="status"></span></td>`;
    tr.querySelector("a").href = "/runs/" + encodeURIComponent(r.id);
    if (known && !known.has(r.id)) tr.className = "new";
    rowsById.set(r.id, tr);
  }
  setText(tr.querySelector('[data-f="started"]'), guadal.when(r.started_at));
  setText(tr.querySelector("a"), r.name);
  for (const f of ["map", "algorithm", "level", "vehicles", "steps"]) setText(tr.querySelector(`[data-f="${f}"]`), r[f]);
  const status = tr.querySelector(".status");
  setText(status, r.status);
  if (status.className !== `status ${r.status}`) status.className = `status ${r.status}`;
  return tr;
}

function render() {
  for (const name of ["map", "algorithm", "level", "status"]) fillSelect(name);
  const wanted = Object.fromEntries(["map", "algorithm", "level", "status"].map((n) => [n, filters.elements[n].value]));
  const shown = runs.filter((r) => Object.entries(wanted).every(([k, v]) => !v || String(r[k]) === v));
  shown.forEach((r, i) => {
    const tr = rowFor(r);
    if (tbody.children[i] !== tr) tbody.insertBefore(tr, tbody.children[i] ?? null);
  });
  while (tbody.children.length > shown.length) tbody.lastElementChild.remove();
  const ids = new Set(runs.map((r) => r.id));
  for (const id of rowsById.keys()) if (!ids.has(id)) rowsById.delete(id);
  document.getElementById("empty").hidden = shown.length > 0;
  known = ids;
}

tbody.addEventListener("click", (e) => {
  const row = e.target.closest("tr");
  if (row && e.target.tagName !== "A") location.href = "/runs/" + encodeURIComponent(row.dataset.id);
});
filters.addEventListener("change", render);

guadal.showUser().then(() => {
  guadal.stream("/api/runs/stream", { runs: (data) => { runs = data.runs; render(); } });
});
