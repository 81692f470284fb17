// The mission list: newest first, filtered in the page, new runs arrive over the live stream.
"use strict";

const filters = document.getElementById("filters");
const tbody = document.querySelector("#runs tbody");
let runs = [];
let known = null;

function fillSelect(name) {
  const select = filters.elements[name];
  const current = select.value;
  const values = [...new Set(runs.map((r) => r[name]).filter((v) => v !== null && v !== undefined))].sort();
  select.innerHTML = '<option value="">any</option>' +
    values.map((v) => `<option${v === current ? " selected" : ""}>${guadal.esc(v)}</option>`).join("");
}

function render() {
  for (const name of ["map", "algorithm", "level", "status"]) fillSelect(name);
  const wanted = Object.fromEntries(["map", "algorithm", "level", "status"].map((n) => [n, filters.elements[n].value]));
  const shown = runs.filter((r) => Object.entries(wanted).every(([k, v]) => !v || String(r[k]) === v));
  tbody.innerHTML = shown.map((r) => `
    <tr data-id="${guadal.esc(r.id)}" class="${known && !known.has(r.id) ? "new" : ""}">
      <td>${guadal.esc(guadal.when(r.started_at))}</td><td><a href="/runs/${encodeURIComponent(r.id)}">${guadal.esc(r.name)}</a></td>
      <td>${guadal.esc(r.map)}</td><td>${guadal.esc(r.algorithm)}</td><td>${guadal.esc(r.level)}</td>
      <td class="num">${guadal.esc(r.vehicles)}</td><td class="num">${guadal.esc(r.steps)}</td>
      <td><span class="status ${guadal.esc(r.status)}">${guadal.esc(r.status)}</span></td>
    </tr>`).join("");
  document.getElementById("empty").hidden = shown.length > 0;
  known = new Set(runs.map((r) => r.id));
}

tbody.addEventListener("click", (e) => {
  const row = e.target.closest("tr");
  if (row && e.target.tagName !== "A") location.href = "/runs/" + encodeURIComponent(row.dataset.id);
});
filters.addEventListener("change", render);

guadal.showUser().then(() => {
  guadal.stream("/api/runs/stream", { runs: (data) => { runs = data.runs; render(); } });
});
