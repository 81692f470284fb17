// One mission, live or replayed: the lake from the map's own grid, tracks, targets, fields,
// metric curves, the boats' state and the samples, all fed by one server-sent event stream.
"use strict";

const runId = decodeURIComponent(location.pathname.split("/").pop());
const PALETTE = ["#e63946", "#1d7fd6", "#2a9d8f", "#f4a261", "#8e44ad", "#d35400", "#16a085", "#c0392b", "#2c3e50", "#b8860b"];
const VIRIDIS = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];
const $ = (id) => document.getElementById(id);

const state = {
  info: null, steps: [], track: [], samples: [], events: [], fields: [], vehicles: {},
  status: [], targets: [], // vehicles.csv and targets.csv rows, in the order they were recorded
  maxStep: 0, view: 0,
};
let map, cells, chart, dirty = false;
const layers = { tracks: {}, plans: {}, boats: {}, targets: {}, targetMarks: {}, nodes: null };

function colourOf(v) { return PALETTE[v % PALETTE.length]; }

function ramp(t) {
  t = Math.min(1, Math.max(0, t)) * (VIRIDIS.length - 1);
  const i = Math.min(VIRIDIS.length - 2, Math.floor(t)), f = t - i;
  const c = VIRIDIS[i].map((a, k) => Math.round(a + (VIRIDIS[i + 1][k] - a) * f));
  return `rgb(${c[0]},${c[1]},${c[2]})`;
}

// --- the lake and the field layer: one canvas, one square per grid cell ------------------
const CellLayer = L.Layer.extend({
  onAdd(m) {
    this._canvas = L.DomUtil.create("canvas", "cells");
    m.getPane("cells").appendChild(this._canvas);
    m.on("moveend zoomend resize", this.redraw, this);
    this.redraw();
  },
  onRemove(m) { this._canvas.remove(); m.off("moveend zoomend resize", this.redraw, this); },
  redraw() {
    if (!this._map || !state.info) return;
    const m = this._map, size = m.getSize(), canvas = this._canvas;
    L.DomUtil.setPosition(canvas, m.containerPointToLayerPoint([0, 0]));
    canvas.width = size.x; canvas.height = size.y;
    const ctx = canvas.getContext("2d");
    const grid = state.info.grid;
    const centre = m.getCenter();
    const metresPerPixel = 40075016.686 * Math.cos(centre.lat * Math.PI / 180) / Math.pow(2, m.getZoom() + 8);
    const side = grid.cell_size_m / metresPerPixel + 1;
    const field = currentField();
    for (let i = 0; i < grid.nodes.length; i++) {
      const p = m.latLngToContainerPoint(grid.nodes[i]);
      if (field) {
        const v = field.values[i];
        ctx.fillStyle = v === null || v === undefined ? "#bcd" : ramp((v - field.min) / (field.max - field.min || 1));
      } else {
        ctx.fillStyle = "#9ecae1";
      }
      ctx.fillRect(p.x - side / 2, p.y - side / 2, side, side);
    }
  },
});

function currentField() {
  const name = $("field").value;
  if (!name) return null;
  let snap = null;
  for (const s of state.fields) if (s.step <= state.view && s.values[name]) snap = s;
  if (!snap) snap = state.fields.find((s) => s.values[name]);
  if (!snap) return null;
  const values = snap.values[name];
  const finite = values.filter((v) => v !== null && Number.isFinite(v));
  const min = Math.min(...finite), max = Math.max(...finite);
  return { values, min, max, step: snap.step };
}

function drawLegend() {
  const f = currentField();
  const el = $("legend");
  if (!f) { el.innerHTML = ""; return; }
  const stops = [0, 0.25, 0.5, 0.75, 1].map((t) => `${ramp(t)} ${t * 100}%`).join(",");
  el.innerHTML = `${guadal.num(f.min)} <span class="bar" style="background:linear-gradient(to right,${stops})"></span> ${guadal.num(f.max)} <small>(step ${f.step})</small>`;
}

// --- boats --------------------------------------------------------------------------------
function boatIcon(v, heading) {
  const svg = `<svg class="boat-icon" viewBox="-10 -10 20 20" style="transform:rotate(${heading}deg)">
    <polygon points="0,-9 6,7 0,3 -6,7" fill="${colourOf(v)}" stroke="#000" stroke-width="1"/></svg>`;
  return L.divIcon({ html: svg, className: `boat boat-${v}`, iconSize: [18, 18], iconAnchor: [9, 9] });
}

function targetIcon(v) {
  const svg = `<svg viewBox="-8 -8 16 16" width="16" height="16"><circle r="6" fill="none" stroke="${colourOf(v)}" stroke-width="2"/>
    <path d="M-3,-3L3,3M-3,3L3,-3" stroke="${colourOf(v)}" stroke-width="1.5"/></svg>`;
  return L.divIcon({ html: svg, className: `target target-${v}`, iconSize: [16, 16], iconAnchor: [8, 8] });
}

// The latest row per vehicle recorded at or before step `upTo` (the live end, or the slider's step).
function latestUpTo(rows, upTo) {
  const out = {};
  for (const r of rows) if (r.step <= upTo) out[r.vehicle] = r;
  return out;
}

function bearing(a, b) {
  const toRad = Math.PI / 180, dLon = (b[1] - a[1]) * toRad;
  const y = Math.sin(dLon) * Math.cos(b[0] * toRad);
  const x = Math.cos(a[0] * toRad) * Math.sin(b[0] * toRad) - Math.sin(a[0] * toRad) * Math.cos(b[0] * toRad) * Math.cos(dLon);
  return (Math.atan2(y, x) / toRad + 360) % 360;
}

function drawMap() {
  const upTo = state.view;
  const bySource = { plan: {}, gps: {} };
  for (const r of state.track) {
    if (r.step > upTo) continue;
    ((bySource[r.source] ||= {})[r.vehicle] ||= []).push([r.lat, r.lon]);
  }
  const vehicles = new Set([...Object.keys(bySource.plan), ...Object.keys(bySource.gps)].map(Number));
  const targets = latestUpTo(state.targets, upTo);
  for (const v of vehicles) {
    const plan = bySource.plan[v] || [], gps = bySource.gps[v] || [];
    const colour = colourOf(v);
    (layers.plans[v] ||= L.polyline([], { color: colour, weight: 1, dashArray: "3 4", opacity: 0.8 }).addTo(map)).setLatLngs(plan);
    (layers.tracks[v] ||= L.polyline([], { color: colour, weight: 2.5 }).addTo(map)).setLatLngs(gps);
    const path = gps.length ? gps : plan;
    if (!path.length) continue;
    const here = path[path.length - 1];
    let heading = 0;
    for (let i = path.length - 2; i >= 0; i--) {
      if (path[i][0] !== here[0] || path[i][1] !== here[1]) { heading = bearing(path[i], here); break; }
    }
    if (!layers.boats[v]) {
      layers.boats[v] = L.marker(here, { icon: boatIcon(v, heading), zIndexOffset: 1000 }).addTo(map);
      layers.boats[v].bindTooltip(`boat ${v}`);
    } else {
      layers.boats[v].setLatLng(here).setIcon(boatIcon(v, heading));
    }
    const target = targets[v];
    if (target) {
      const t = [target.lat, target.lon];
      (layers.targets[v] ||= L.polyline([], { color: colour, weight: 1.5, dashArray: "6 4" }).addTo(map)).setLatLngs([here, t]);
      if (!layers.targetMarks[v]) {
        layers.targetMarks[v] = L.marker(t, { icon: targetIcon(v), zIndexOffset: 500 }).addTo(map);
        layers.targetMarks[v].bindTooltip(`boat ${v}'s target`);
      }
      layers.targetMarks[v].setLatLng(t).getElement()?.setAttribute("data-node", target.node);
    } else {
      if (layers.targets[v]) layers.targets[v].setLatLngs([]);
      if (layers.targetMarks[v]) { layers.targetMarks[v].remove(); delete layers.targetMarks[v]; }
    }
  }
  // planned nodes: every node a plan row visited, as small dots
  const seen = new Set();
  const dots = [];
  for (const r of state.track) {
    if (r.source !== "plan" || r.step > upTo || r.node === null || seen.has(r.node)) continue;
    seen.add(r.node);
    dots.push(L.circleMarker([r.lat, r.lon], { radius: 2, color: colourOf(r.vehicle), weight: 1, fillOpacity: 0.9 }));
  }
  if (layers.nodes) layers.nodes.remove();
  layers.nodes = L.layerGroup(dots).addTo(map);
  cells.redraw();
  drawLegend();
}

// --- side panels ---------------------------------------------------------------------------
// A boat's link age as reported, plus the time since that report reached the database while the
// run goes on live: when rows stop coming (a dead link, a stalled mission) the age keeps growing
// on screen instead of freezing at the last, healthy-looking value, on a page opened later too.
function linkAge(b) {
  if (b.link_age_s === null) return "—";
  const live = state.view >= state.maxStep && state.info.run.status === "running" && b.heard !== null;
  const age = b.link_age_s + (live ? (performance.now() - b.heard) / 1000 : 0);
  return guadal.num(age, 2) + " s";
}

function drawBoats() {
  // Rows are updated in place, never rebuilt: a panel redrawn under the pointer between press and
  // release would swallow an operator's click on "hold" or "release".
  const controls = state.info.controls && state.info.user && state.info.run.status === "running";
  const tbody = $("boats").querySelector("tbody");
  const rows = Object.values(state.vehicles).sort((a, b) => a.vehicle - b.vehicle);
  for (const b of rows) {
    let tr = tbody.querySelector(`tr[data-vehicle="${b.vehicle}"]`);
    if (!tr) {
      tr = document.createElement("tr");
      tr.dataset.vehicle = b.vehicle;
      tr.innerHTML = `<td><span style="color:${colourOf(b.vehicle)}">&#9650;</span> ${b.vehicle}</td>
        <td class="num" data-field="remaining"></td><td data-field="mode"></td><td data-field="armed"></td>
        <td class="num" data-field="battery"></td><td class="num" data-field="link"></td>
        <td data-field="fault"></td><td class="control"></td>`;
      tbody.appendChild(tr);
    }
    const text = {
      remaining: guadal.num(b.remaining, 4),
      mode: b.mode ?? "—",
      armed: b.armed === null ? "—" : b.armed ? "yes" : "no",
      battery: b.battery === null ? "—" : guadal.num(b.battery) + " %",
      link: linkAge(b),
      fault: b.last_fault ?? "",
    };
    for (const [field, value] of Object.entries(text)) {
      const td = tr.querySelector(`td[data-field="${field}"]`);
      if (td.textContent !== value) td.textContent = value;
    }
    const cell = tr.querySelector("td.control");
    let button = cell.querySelector("button");
    if (!controls) { if (button) button.remove(); continue; }
    if (!button) {
      button = document.createElement("button");
      button.dataset.vehicle = b.vehicle;
      cell.appendChild(button);
    }
    const action = b.held ? "release" : "hold";
    if (button.dataset.action !== action) { button.dataset.action = action; button.textContent = action; }
  }
}

function drawSamples() {
  const shown = state.samples.filter((s) => s.step <= state.view);
  $("sample-count").textContent = `(${shown.length})`;
  $("samples").querySelector("tbody").innerHTML = shown.slice(-40).reverse().map((s) => `
    <tr><td class="num">${s.step}</td><td class="num">${s.vehicle}</td><td class="num">${s.node ?? ""}</td>
    <td class="num">${Number(s.lat).toFixed(6)}</td><td class="num">${Number(s.lon).toFixed(6)}</td>
    <td class="num">${guadal.num(s.value, 4)}</td></tr>`).join("");
}

function drawEvents() {
  $("events").innerHTML = state.events.slice(-100).reverse().map((e) =>
    `<li>${guadal.esc(guadal.when(e.at))} <b>${guadal.esc(e.kind)}</b>${e.vehicle === null || e.vehicle === undefined ? "" : " boat " + e.vehicle}
     ${guadal.esc(e.detail || "")}${e.who ? " — " + guadal.esc(e.who) : ""}</li>`).join("");
}

function drawChart() {
  const metric = $("metric").value, xName = $("xaxis").value;
  const rows = state.steps.filter((s) => s.step <= state.view);
  const data = [rows.map((r) => r.metrics[xName] ?? r[xName]), rows.map((r) => r.metrics[metric])];
  const el = $("chart");
  if (!chart || chart._key !== metric + xName) {
    if (chart) chart.destroy();
    chart = new uPlot({
      width: el.clientWidth || 500, height: 200,
      scales: { x: { time: false } },
      axes: [{ label: xName === "time_s" ? "mission time (s)" : "fleet distance (m)" }, { label: metric }],
      series: [{}, { label: metric, stroke: "#1d3557", width: 2 }],
      legend: { show: false },
    }, data, el);
    chart._key = metric + xName;
  } else {
    chart.setData(data);
  }
}

function drawHeader() {
  const run = state.info.run;
  $("title").textContent = `${run.name} · ${run.algorithm} · ${run.level}`;
  $("status").textContent = run.status;
  $("status").className = "status " + run.status;
  $("step").textContent = state.maxStep;
  $("controls").hidden = !(state.info.controls && state.info.user && run.status === "running");
  const slider = $("slider");
  slider.max = state.maxStep;
  if ($("follow").checked) { slider.value = state.maxStep; state.view = state.maxStep; }
  $("slider-label").textContent = `step ${state.view} / ${state.maxStep}`;
}

function render() {
  dirty = false;
  drawHeader();
  updateBoats();
  drawMap();
  drawBoats();
  drawSamples();
  drawEvents();
  drawChart();
}

function schedule() {
  if (!dirty) { dirty = true; requestAnimationFrame(render); }
}

// --- live data ----------------------------------------------------------------------------
function apply(update) {
  if (update.run) Object.assign(state.info.run, update.run);
  state.steps.push(...(update.steps || []));
  state.track.push(...(update.track || []));
  state.samples.push(...(update.measurements || []));
  state.events.push(...(update.events || []));
  // the link's age counts up from when the newest row reached the database (the server says how
  // long ago): on a page opened after the boats went quiet, from then, not from the page's load
  const heard = performance.now() - 1000 * (update.vehicles_age_s || 0);
  for (const r of update.vehicles || []) r.heard = heard;
  state.status.push(...(update.vehicles || []));
  state.targets.push(...(update.targets || []));
  state.fields.push(...(update.fields || []));
  if (state.fields.length > 600) state.fields.splice(0, state.fields.length - 600); // a long mission's live maps
  for (const s of update.fields || []) {
    for (const name of Object.keys(s.values)) {
      if (![...$("field").options].some((o) => o.value === name)) $("field").add(new Option(name, name));
    }
  }
  for (const s of update.steps || []) {
    for (const name of Object.keys(s.metrics)) {
      if (![...$("metric").options].some((o) => o.value === name) && name !== "step") {
        $("metric").add(new Option(name, name));
        if (name === state.info.default_metric) $("metric").value = name;
      }
    }
  }
  const last = state.steps.length ? state.steps[state.steps.length - 1].step : 0;
  state.maxStep = Math.max(state.maxStep, last, state.info.run.steps || 0);
  schedule();
}

// Per boat, at the step shown: what it last reported (vehicles.csv: budget left, mode, armed,
// battery, link age, fault); held/paused from the operators' events; no row yet: the budget
// from the latest metrics row.
function updateBoats() {
  const n = state.info.run.vehicles || 0;
  const last = state.steps.length ? state.steps[state.steps.length - 1].metrics : {};
  const reported = latestUpTo(state.status, state.view);
  const shown = state.steps.find((r) => r.step === state.view);
  const until = state.view >= state.maxStep || !shown ? Infinity : shown.time_s; // replay: events until then
  let paused = false;
  const held = {}, fault = {};
  for (const e of state.events) {
    if (e.time_s !== null && e.time_s !== undefined && e.time_s > until) continue;
    if (e.kind === "control") {
      const action = e.action;
      if (action === "pause") paused = true;
      if (action === "resume") paused = false;
      if (action === "hold" && e.vehicle !== null) held[e.vehicle] = true;
      if (action === "release" && e.vehicle !== null) held[e.vehicle] = false;
    } else if (e.vehicle !== null && e.vehicle !== undefined) {
      fault[e.vehicle] = `${e.kind}: ${e.detail || ""}`;
    }
  }
  for (let v = 0; v < n; v++) {
    const used = last[`distance_v${v}`];
    const budget = state.info.max_distance;
    const r = reported[v] || {};
    const operator = held[v] ? " · held" : paused ? " · paused" : "";
    state.vehicles[v] = {
      vehicle: v,
      remaining: r.remaining ?? (budget === null || budget === undefined || used === undefined ? null : Math.max(0, budget - used)),
      mode: r.mode ? r.mode + operator : null,
      armed: r.armed ?? null,
      battery: r.battery ?? null,
      link_age_s: r.link_age_s ?? null,
      heard: r.heard ?? null,
      held: !!held[v],
      last_fault: r.fault || fault[v] || "",
    };
  }
  state.paused = paused;
}

async function control(action, vehicle) {
  const el = $("control-state");
  try {
    const r = await guadal.postJSON(`/api/runs/${encodeURIComponent(runId)}/control`, { action, vehicle });
    el.textContent = `${action} sent`;
    return r;
  } catch (err) {
    el.textContent = err.message;
  }
}

async function start() {
  const info = await guadal.getJSON(`/api/runs/${encodeURIComponent(runId)}`);
  state.info = info;
  await guadal.showUser();
  const nodes = info.grid.nodes;
  map = L.map("map", { zoomAnimation: false, preferCanvas: false, attributionControl: !!info.tiles });
  map.createPane("cells").style.zIndex = 350;
  if (info.tiles) L.tileLayer(info.tiles, { maxZoom: 20, attribution: info.tiles_attribution || "" }).addTo(map);
  map.fitBounds(L.latLngBounds(nodes), { padding: [10, 10] });
  cells = new CellLayer().addTo(map);
  $("downloads").innerHTML = info.downloads.map((d) => `<a href="${guadal.esc(d.href)}" download>${guadal.esc(d.label)}</a>`).join("");
  $("field").addEventListener("change", schedule);
  $("metric").addEventListener("change", schedule);
  $("xaxis").addEventListener("change", schedule);
  $("follow").addEventListener("change", () => { if ($("follow").checked) state.view = state.maxStep; schedule(); });
  $("slider").addEventListener("input", () => {
    state.view = Number($("slider").value);
    $("follow").checked = state.view >= state.maxStep;
    schedule();
  });
  document.querySelector(".side-col").addEventListener("click", (e) => {
    const b = e.target.closest("button[data-action]");
    if (b) control(b.dataset.action, b.dataset.vehicle === undefined ? null : Number(b.dataset.vehicle));
  });
  guadal.stream(`/api/runs/${encodeURIComponent(runId)}/stream`, { update: apply });
  setInterval(drawBoats, 1000); // the link ages count up between rows
}

start();
