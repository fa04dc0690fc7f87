// neuralbrdf view: the page. It builds its controls from /api/scene, keeps its state in the URL
// (?theta_i=30&wavelength=600...), asks /api/views for the views a change makes stale (one request
// at a time; changes made meanwhile are sent together when it returns) and draws them with plotly.js.
// Only views on screen are redrawn at once; the others are marked stale (body[data-stale]) and
// redrawn when they scroll into view. A view the server answers "unchanged" is not redrawn.
// window.viewerTimings records every update: the server's, the network's and the drawing's time.
"use strict";

// Controls the page applies itself (no request): what each looks like and the views it redraws.
const LOCAL = {
  scale: {label: "scale", choices: [["linear", "linear"], ["log", "log"]], default: "linear",
          views: ["inplane", "lobe", "spectrum"]},
  lobe_azimuth: {label: "camera azimuth", unit: "°", min: -180, max: 180, step: 5, default: -70, views: ["lobe"]},
  lobe_elevation: {label: "camera elevation", unit: "°", min: 0, max: 90, step: 5, default: 20, views: ["lobe"]},
};
// Where each control sits: the sticky bar (views it feeds: several) or the one view it feeds.
const HOME = {theta_i: "global", wavelength: "global", channel: "global", cosine: "global", scale: "global",
              lobe_azimuth: "lobe", lobe_elevation: "lobe",
              plane_phi: "inplane", pick_theta: "spectrum", pick_phi: "spectrum", hemisphere: "hemisphere",
              phi_d: "halfdiff", light_theta: "sphere", light_phi: "sphere", exposure: "sphere", sphere: "sphere"};
const TRUTH_COLOUR = "#000000";
const PALETTE = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2"];
const CONFIG = {displaylogo: false, responsive: true};
const SMALL = {...CONFIG, displayModeBar: false};  // small charts: their titles stay readable
// matplotlib's magma (as neuralbrdf evaluate's error maps), which plotly.js does not name
const MAGMA = [[0, "#000004"], [0.125, "#1c1044"], [0.25, "#4f127b"], [0.375, "#812581"], [0.5, "#b5367a"],
               [0.625, "#e55064"], [0.75, "#fb8761"], [0.875, "#fec287"], [1, "#fcfdbf"]];
const FONT = {size: 13};

let scene = null;
const state = {};
const last = {};          // the last payload of each view
const colours = {};       // file label -> colour
const timings = [];
window.viewerTimings = timings;

const $ = (id) => document.getElementById(id);
const pending = new Set();
const visible = new Set();  // views at least partly on screen
const stale = new Set();    // views whose state changed while off screen
let pendingSince = null;
let busy = false;

// ------------------------------------------------------------------ state and controls

function controlOf(name) {
  return scene.controls[name] || LOCAL[name];
}

function readUrl() {
  const query = new URLSearchParams(window.location.search);
  for (const [name, control] of [...Object.entries(scene.controls), ...Object.entries(LOCAL)]) {
    state[name] = control.default;
    if (!query.has(name)) continue;
    const text = query.get(name);
    if (control.choices) {
      if (control.choices.some(([value]) => value === text)) state[name] = text;
    } else if (text.trim() !== "" && Number.isFinite(Number(text))) {
      state[name] = Math.min(control.max, Math.max(control.min, Number(text)));
    }
  }
}

function writeUrl() {
  const query = new URLSearchParams();
  for (const [name, value] of Object.entries(state)) {
    if (value !== controlOf(name).default) query.set(name, value);
  }
  const text = query.toString();
  window.history.replaceState(null, "", text ? `?${text}` : window.location.pathname);
}

function formatted(name, value) {
  const control = controlOf(name);
  return `${Number(value).toFixed(control.step < 1 ? 1 : 0)} ${control.unit}`;
}

function addControl(name, control) {
  const home = HOME[name] === "global" ? $("controls-global") : document.querySelector(`[data-home=${HOME[name]}]`);
  const label = document.createElement("label");
  label.className = "control";
  label.append(control.label);
  let input;
  if (control.choices) {
    input = document.createElement("select");
    for (const [value, text] of control.choices) input.add(new Option(text, value, false, value === state[name]));
    input.addEventListener("change", () => changed(name, input.value));
    label.append(input);
  } else {
    input = document.createElement("input");
    Object.assign(input, {type: "range", min: control.min, max: control.max, step: control.step, value: state[name]});
    const shown = document.createElement("output");
    shown.textContent = formatted(name, state[name]);
    input.addEventListener("input", () => changed(name, Number(input.value)));
    if (name === "theta_i" && scene.measured) {  // tick marks at the measured incident angles
      const ticks = document.createElement("datalist");
      ticks.id = "measured-theta-i";
      for (const angle of scene.measured.theta_i) ticks.append(new Option("", angle));
      label.append(ticks);
      input.setAttribute("list", ticks.id);
    }
    label.append(input, shown);
  }
  input.id = `control-${name}`;
  input.name = name;
  home.append(label);
}

function changed(name, value) {
  apply({[name]: value});
}

// Set controls (state, URL, sliders) and redraw what they feed: one request for all of them.
function apply(changes) {
  Object.assign(state, changes);
  writeUrl();
  for (const [name, value] of Object.entries(changes)) {
    const input = $(`control-${name}`);
    if (input && String(input.value) !== String(value)) input.value = value;
    if (input && input.nextElementSibling) input.nextElementSibling.textContent = formatted(name, value);
  }
  const names = Object.keys(changes);
  if (names.every((name) => name in LOCAL)) {
    const since = performance.now();
    const views = [...new Set(names.flatMap((name) => LOCAL[name].views))].filter((view) => last[view]);
    for (const view of views) DRAW[view](last[view]);
    timings.push({cause: names.join("+"), views, server_ms: 0, fetch_ms: 0, total_ms: performance.now() - since});
    return;
  }
  const affected = Object.keys(scene.views).filter((view) => names.some((name) => scene.views[view].includes(name)));
  for (const view of affected) if (!visible.has(view)) stale.add(view);
  markStale();
  schedule(affected.filter((view) => visible.has(view)), names.join("+"));
}

function markStale() {
  document.body.dataset.stale = [...stale].join(",");
}

// Resolves after the first report of which views are on screen (those are then being drawn).
function watchVisibility() {
  return new Promise((resolve) => {
    const observer = new IntersectionObserver((entries) => {
      for (const entry of entries) {
        const view = entry.target.id.replace("view-", "");
        if (!entry.isIntersecting) {
          visible.delete(view);
          continue;
        }
        visible.add(view);
        if (stale.delete(view)) {
          markStale();
          schedule([view], "scrolled into view");
        }
      }
      resolve();
    });
    for (const view of Object.keys(scene.views)) observer.observe($(`view-${view}`));
  });
}

// ------------------------------------------------------------------ requests

function schedule(views, cause) {
  if (!views.length) return;
  for (const view of views) pending.add(view);
  if (pendingSince === null) pendingSince = {time: performance.now(), cause};
  if (!busy) pump();
}

async function pump() {
  busy = true;
  document.body.dataset.busy = "1";
  while (pending.size) {
    const views = [...pending];
    const since = pendingSince;
    pending.clear();
    pendingSince = null;
    try {
      await refresh(views, since);
    } catch (error) {
      showStatus(`error: ${error.message}`, true);
    }
  }
  busy = false;
  document.body.dataset.busy = "0";
}

async function refresh(views, since) {
  const query = new URLSearchParams({views: views.join(",")});
  for (const [name, value] of Object.entries(state)) if (name in scene.controls) query.set(name, value);
  const known = views.filter((view) => last[view]).map((view) => `${view}:${last[view].key}`);
  if (known.length) query.set("known", known.join(","));
  const response = await fetch(`api/views?${query}`);
  const answer = await response.json();
  if (!response.ok) throw new Error(answer.error);
  const fetched = performance.now();
  const drawn = {};
  for (const view of views) {
    if (answer.views[view].unchanged) continue;
    const begin = performance.now();
    last[view] = answer.views[view];
    await DRAW[view](answer.views[view]);
    drawn[view] = performance.now() - begin;
  }
  await new Promise((resolve) => requestAnimationFrame(() => resolve()));
  const done = performance.now();
  const server = views.reduce((sum, view) => sum + answer.views[view].server_ms, 0);
  const timing = {cause: since.cause, views, server_ms: server, fetch_ms: fetched - since.time,
                  draw_ms: done - fetched, draw_by_view_ms: drawn, total_ms: done - since.time};
  timings.push(timing);
  document.body.dataset.updates = String(timings.length);
  showStatus(`${since.cause}: ${Object.keys(drawn).join(", ") || "nothing"} redrawn in ${timing.total_ms.toFixed(0)} ms ` +
             `(server ${server.toFixed(0)} ms, drawing ${timing.draw_ms.toFixed(0)} ms)`);
}

function showStatus(text, error = false) {
  const status = $("status");
  status.textContent = text;
  status.classList.toggle("error", error);
}

// ------------------------------------------------------------------ labels

function quantity() {
  const f = state.cosine === "f_cos" ? "f · cos θi" : "f";
  const channel = {wavelength: `at λ = ${state.wavelength} nm`, Y: "luminance Y", R: "red", G: "green",
                   B: "blue"}[state.channel];
  return `${f}, ${channel}`;
}

function title(text) {
  return {text, font: {size: 14}, x: 0, xanchor: "left"};
}

function noteMissing(view, payload) {
  // why each file left out has no value here: an RGB file at one wavelength, a spectral one without colour
  const note = document.querySelector(`#view-${view} .missing`);
  if (note) note.textContent = (payload.missing || []).map((label) => {
    const source = scene.sources.find((s) => s.label === label);
    return source && source.spectral ? `${label}: no colour: ${source.no_colour}`
      : `${label}: an RGB file has no value at one wavelength`;
  }).join("; ");
}

function role(label) {
  return scene.sources.find((source) => source.label === label)?.role;
}

function styled(label) {
  return role(label) === "truth" ? {color: TRUTH_COLOUR, dash: "dash"} : {color: colours[label]};
}

function nameOf(label) {
  return role(label) === "truth" ? `${label} (truth)` : label;
}

// ------------------------------------------------------------------ views

function drawInplane(payload) {
  noteMissing("inplane", payload);
  const traces = payload.curves.map((curve) => ({
    x: payload.x, y: curve.y, name: nameOf(curve.label), mode: "lines", line: {...styled(curve.label), width: 2},
    hovertemplate: "θr %{x}°: %{y:.4g} sr⁻¹",
  }));
  if (payload.measured) {
    traces.push({x: payload.measured.x, y: payload.measured.y, name: `${payload.measured.label} (measured)`,
                 mode: "markers", marker: {symbol: "circle-open", size: 7, color: "#444"}});
  }
  const inPlane = state.plane_phi === 0;
  const layout = {
    font: FONT, margin: {t: 36, r: 10, b: 50, l: 70}, legend: {orientation: "h", y: -0.2},
    hovermode: "x",  // a click anywhere above or below the curves picks its outgoing angle, not only on one
    title: title(`θi = ${state.theta_i}°, plane at φ = ${state.plane_phi}°`),
    xaxis: {title: {text: inPlane ? "θr, signed outgoing angle in the plane of incidence (°; mirror at θr = θi)"
                                  : `signed outgoing angle in the plane at φ = ${state.plane_phi}° (°)`},
            range: [-90, 90], dtick: 15},
    yaxis: {title: {text: `${quantity()} (sr⁻¹)`}, type: state.scale},
    shapes: inPlane ? [{type: "line", x0: state.theta_i, x1: state.theta_i, yref: "paper", y0: 0, y1: 1,
                        line: {color: "#999", dash: "dot", width: 1}}] : [],
  };
  const div = $("plot-inplane");
  return Plotly.react(div, traces, layout, CONFIG).then(() =>  // a click picks the direction of the spectrum view
    pickOnClick(div, (x) => [Math.abs(x), x > 0 ? state.plane_phi + 180 : state.plane_phi]));
}

function hemisphereMarks() {
  const reach = 90, phi = state.plane_phi * Math.PI / 180;
  const pick = [state.pick_theta * Math.cos(state.pick_phi * Math.PI / 180),
                state.pick_theta * Math.sin(state.pick_phi * Math.PI / 180)];
  return [
    {x: [-reach * Math.cos(phi), reach * Math.cos(phi)], y: [-reach * Math.sin(phi), reach * Math.sin(phi)],
     mode: "lines", line: {color: "white", width: 1, dash: "dot"}, hoverinfo: "skip", showlegend: false},
    {x: [-state.theta_i], y: [0], mode: "markers", marker: {symbol: "x-thin", size: 10, line: {color: "white", width: 2}},
     hoverinfo: "skip", showlegend: false},
    {x: [pick[0]], y: [pick[1]], mode: "markers", marker: {symbol: "circle-open", size: 12, color: "#ff4081",
     line: {width: 2}}, hoverinfo: "skip", showlegend: false},
  ];
}

function squareAxes(text) {
  return {title: {text}, range: [-90, 90], dtick: 30, zeroline: false, constrain: "domain"};
}

// Small charts of one row share their colour scale: it is drawn beside the last one only (a colour
// bar costs about as much to draw as its chart), in a right margin every chart keeps alike.
function smallLayout(heading, axes) {
  return {font: FONT, margin: {t: 30, r: 96, b: 46, l: 54}, title: title(heading), showlegend: false,
          xaxis: axes.x, yaxis: {...axes.y, scaleanchor: "x", constrain: "domain"}, images: []};
}

function plotGrid(container, count) {
  const grid = $(container);
  while (grid.children.length > count) grid.lastChild.remove();
  while (grid.children.length < count) {
    const div = document.createElement("div");
    div.className = "plot";
    div.id = `${container}-${grid.children.length}`;
    grid.append(div);
  }
  return [...grid.children];
}

function pickOnClick(div, toPick) {
  if (div.dataset.bound) return;
  div.dataset.bound = "1";
  div.on("plotly_click", (event) => {
    const point = event.points[0];
    const pick = toPick(point.x, point.y);
    if (!pick) return;
    apply({pick_theta: Math.round(pick[0]), pick_phi: Math.round(((pick[1] % 360) + 360) % 360) % 360});
  });
}

function drawHemisphere(payload) {
  noteMissing("hemisphere", payload);
  const divs = plotGrid("plots-hemisphere", payload.maps.length);
  const axes = {x: squareAxes("θo cos φo (°)"), y: squareAxes("θo sin φo (°)")};
  const ratios = drawRatios("plots-hemisphere-diff", payload, axes, "%{x:.0f}°, %{y:.0f}°");
  return Promise.all([...ratios, ...payload.maps.map((map, k) => {
    const layout = smallLayout(nameOf(map.label), axes);
    const traces = [];
    if (map.png) {
      layout.images = [{source: map.png, xref: "x", yref: "y", x: -90, y: 90, sizex: 180, sizey: 180,
                        sizing: "stretch", layer: "below"}];
      const zeros = payload.axis.map(() => payload.axis.map(() => 0));  // invisible: it takes the clicks
      traces.push({type: "heatmap", x: payload.axis, y: payload.axis, z: zeros, opacity: 0, showscale: false,
                   hovertemplate: "%{x:.0f}°, %{y:.0f}°<extra></extra>"});
    } else {
      traces.push({type: "heatmap", x: payload.axis, y: payload.axis, z: map.z, zmin: payload.zrange[0],
                   zmax: payload.zrange[1], colorscale: "Viridis", hoverongaps: false,
                   showscale: k === payload.maps.length - 1,
                   colorbar: {title: {text: `log₁₀ ${state.cosine === "f_cos" ? "f·cos θi" : "f"} (sr⁻¹)`, side: "right"},
                              thickness: 12},
                   hovertemplate: "%{x:.0f}°, %{y:.0f}°: 10^%{z:.2f} sr⁻¹<extra></extra>"});
    }
    traces.push(...hemisphereMarks());
    return Plotly.react(divs[k], traces, layout, SMALL).then(() =>
      pickOnClick(divs[k], (x, y) => Math.hypot(x, y) < 90 ? [Math.hypot(x, y), Math.atan2(y, x) * 180 / Math.PI] : null));
  })]);
}

function lobeRadius(value) {
  if (state.scale === "linear") return Math.max(value, 0);
  return value > 1e-3 ? Math.log10(value / 1e-3) : 0;
}

// An orthographic camera at azimuth az and elevation el (degrees): a point's position on the screen.
function camera(az, el) {
  const a = az * Math.PI / 180, e = el * Math.PI / 180;
  const right = [-Math.sin(a), Math.cos(a), 0];
  const up = [-Math.sin(e) * Math.cos(a), -Math.sin(e) * Math.sin(a), Math.cos(e)];
  return (p) => [p[0] * right[0] + p[1] * right[1], p[0] * up[0] + p[1] * up[1] + p[2] * up[2]];
}

function niceStep(extent) {
  const raw = extent / 4, power = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 5, 10].map((m) => m * power).find((step) => step >= raw);
}

// The lobe as a wire cage (rings of equal θo, meridians of equal φo) seen through camera(): drawn as
// 2-D lines, cheap on any machine (no WebGL); the camera sliders turn it.
function drawLobe(payload) {
  noteMissing("lobe", payload);
  const nTheta = payload.theta_o.length, nPhi = payload.phi_o.length;
  const view = camera(state.lobe_azimuth, state.lobe_elevation);
  const cages = payload.surfaces.map((surface) => {
    const r = decoded(surface.r);
    const point = (i, j) => {
      const t = payload.theta_o[i] * Math.PI / 180, p = payload.phi_o[j] * Math.PI / 180;
      const radius = lobeRadius(r[i * nPhi + j]);
      return [radius * Math.sin(t) * Math.cos(p), radius * Math.sin(t) * Math.sin(p), radius * Math.cos(t)];
    };
    const lines = [];
    for (let i = 1; i < nTheta; i += 2) lines.push([...Array(nPhi).keys()].map((j) => point(i, j)));
    for (let j = 0; j < nPhi - 1; j += 2) lines.push([...Array(nTheta).keys()].map((i) => point(i, j)));
    return {label: surface.label, lines};
  });
  const extent = Math.max(1e-9, ...cages.flatMap((c) => c.lines.flat().map((p) => Math.hypot(...p))));
  const trace = (lines, extra) => {
    const xy = lines.flatMap((line) => [...line.map(view), [null, null]]);
    return {type: "scatter", mode: "lines", x: xy.map((q) => q[0]), y: xy.map((q) => q[1]), ...extra};
  };
  const traces = cages.map((cage) => trace(cage.lines, {
    name: nameOf(cage.label), hoverinfo: "name",
    line: {color: role(cage.label) === "truth" ? TRUTH_COLOUR : colours[cage.label], width: 1,
           dash: role(cage.label) === "truth" ? "dot" : "solid"}}));
  const ground = [...Array(73).keys()].map((k) => [extent * Math.cos(k * Math.PI / 36), extent * Math.sin(k * Math.PI / 36), 0]);
  const axes = [[[-extent, 0, 0], [extent, 0, 0]], [[0, -extent, 0], [0, extent, 0]], [[0, 0, 0], [0, 0, extent]]];
  const step = niceStep(extent);
  const ticks = [...Array(Math.floor(extent / step)).keys()].map((k) => [0, 0, (k + 1) * step]);
  const w = payload.incident;
  traces.push(trace([ground, ...axes], {line: {color: "#aaa", width: 1}, hoverinfo: "skip", showlegend: false}));
  traces.push(trace([[[0, 0, 0], [w[0] * extent, w[1] * extent, w[2] * extent]]],
                    {line: {color: "black", width: 3}, name: "incident direction", hoverinfo: "name"}));
  const label = (p, text) => {
    const [x, y] = view(p);
    return {x, y, text, showarrow: false, font: {size: 12, color: "#555"}, xanchor: "left", yanchor: "bottom"};
  };
  const unit = state.scale === "linear" ? "sr⁻¹" : "decades above 10⁻³ sr⁻¹";
  const layout = {
    font: FONT, margin: {t: 36, r: 10, b: 10, l: 10}, title: title(`${quantity()} at θi = ${state.theta_i}°: distance from the centre in ${unit}`),
    legend: {x: 0, y: 1}, showlegend: true,
    xaxis: {visible: false}, yaxis: {visible: false, scaleanchor: "x"},
    annotations: [label([extent, 0, 0], "x (φ = 0°, towards the light)"), label([0, extent, 0], "y"),
                  label([0, 0, extent], "z, the normal"),
                  ...ticks.map((p) => label(p, `${+p[2].toPrecision(3)}`))],
  };
  return Plotly.react("plot-lobe", traces, layout, CONFIG);
}

function extentOf(rows) {
  return Math.max(1e-9, ...rows.flat().map(Math.abs));
}

function decoded(typedArray) {  // plotly's {dtype: "f4", bdata} form as a flat Float32Array
  const bytes = Uint8Array.from(atob(typedArray.bdata), (c) => c.charCodeAt(0));
  return new Float32Array(bytes.buffer);
}

const RATIO = {zmid: 0, zmin: -1, zmax: 1, colorscale: "RdBu", reversescale: true,
               colorbar: {thickness: 12, title: {text: "log₁₀(model / truth)", side: "right"}}};

function drawRatios(container, payload, axes, hover) {
  const divs = plotGrid(container, payload.diffs.length);
  return payload.diffs.map((diff, k) => Plotly.react(divs[k], [{
    type: "heatmap", x: payload.axis, y: payload.axis, z: diff.z, hoverongaps: false, ...RATIO,
    showscale: k === payload.diffs.length - 1,
    hovertemplate: `${hover}: %{z:+.2f} decades<extra></extra>`}], smallLayout(`${diff.label} against the truth`, axes),
    SMALL));
}

function drawHalfdiff(payload) {
  noteMissing("halfdiff", payload);
  const axes = {x: {title: {text: "θh, half angle (°)"}, range: [0, 90], dtick: 15, constrain: "domain"},
                y: {title: {text: "θd, difference angle (°)"}, range: [0, 90], dtick: 15}};
  const heat = (z, extra) => [{type: "heatmap", x: payload.axis, y: payload.axis, z, hoverongaps: false, ...extra}];
  const maps = plotGrid("plots-halfdiff", payload.maps.length);
  const value = state.cosine === "f_cos" ? "f·cos θi" : "f";
  return Promise.all([
    ...payload.maps.map((map, k) => Plotly.react(maps[k], heat(map.z, {
      zmin: payload.zrange[0], zmax: payload.zrange[1], colorscale: "Viridis", showscale: k === payload.maps.length - 1,
      colorbar: {thickness: 12, title: {text: `log₁₀ ${value} (sr⁻¹)`, side: "right"}},
      hovertemplate: "θh %{x:.1f}°, θd %{y:.1f}°: 10^%{z:.2f} sr⁻¹<extra></extra>"}),
      smallLayout(`${nameOf(map.label)}, φd = ${state.phi_d}°`, axes), SMALL)),
    ...drawRatios("plots-halfdiff-diff", payload, axes, "θh %{x:.1f}°, θd %{y:.1f}°"),
  ]);
}

function drawSphere(payload) {
  noteMissing("sphere", payload);
  const axes = {x: {title: {text: "x (sphere radii)"}, range: [-1, 1], dtick: 0.5, constrain: "domain", zeroline: false},
                y: {title: {text: "y (sphere radii)"}, range: [-1, 1], dtick: 0.5, zeroline: false}};
  const images = plotGrid("plots-sphere", payload.images.length);
  const diffs = plotGrid("plots-sphere-diff", payload.diffs.length);
  const shown = payload.colour ? "colour" : `at λ = ${state.wavelength} nm`;
  return Promise.all([
    ...payload.images.map((picture, k) => {
      const layout = smallLayout(`${nameOf(picture.label)}, ${shown}`, axes);
      layout.plot_bgcolor = "#303030";
      layout.images = [{source: picture.png, xref: "x", yref: "y", x: -1, y: 1, sizex: 2, sizey: 2, sizing: "stretch",
                        layer: "above"}];
      return Plotly.react(images[k], [{x: [-1, 1], y: [-1, 1], mode: "markers", marker: {opacity: 0}, hoverinfo: "skip"}],
                          layout, SMALL);
    }),
    ...payload.diffs.map((diff, k) => {
      const deltaE = diff.kind === "delta_e2000";
      const trace = {type: "heatmap", x: payload.axis, y: payload.axis, z: diff.z, hoverongaps: false,
                     showscale: k === payload.diffs.length - 1, ...(deltaE ? {zmin: 0, zmax: scene.delta_e_max, colorscale: MAGMA,
                                   colorbar: {thickness: 12, title: {text: "CIEDE2000 ΔE", side: "right"}},
                                   hovertemplate: "ΔE %{z:.2f}<extra></extra>"}
                                : {...RATIO, hovertemplate: "%{z:+.2f} decades<extra></extra>"})};
      const heading = deltaE ? `${diff.label}: ΔE mean ${diff.mean.toFixed(2)}, p95 ${diff.p95.toFixed(2)}`
                             : `${diff.label} against the truth`;
      return Plotly.react(diffs[k], [trace], smallLayout(heading, axes), SMALL);
    }),
  ]);
}

function encoded(linear) {  // IEC 61966-2-1 transfer function, as a display shows a linear value
  const c = Math.min(1, Math.max(0, linear));
  return Math.round(255 * (c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055));
}

function drawSpectrum(payload) {
  const pair = payload.pair;
  const traces = payload.curves.map((curve) => ({
    x: curve.x, y: curve.y, name: nameOf(curve.label), mode: "lines", line: {...styled(curve.label), width: 2},
    hovertemplate: "%{x} nm: %{y:.4g} sr⁻¹",
  }));
  if (payload.measured) {
    traces.push({x: payload.measured.x, y: payload.measured.y, mode: "markers",
                 name: `${payload.measured.label} (measured at θi ${payload.measured.theta_i}°, θr ${payload.measured.theta_r}°)`,
                 marker: {symbol: "circle-open", size: 7, color: "#444"}});
  }
  const layout = {
    font: FONT, margin: {t: 36, r: 10, b: 50, l: 70}, legend: {orientation: "h", y: -0.2},
    title: title(`wi at θi = ${pair.theta_i}°, φi = 0°; wo at θo = ${pair.theta_o}°, φo = ${pair.phi_o}°`),
    xaxis: {title: {text: "λ, wavelength (nm)"}},
    yaxis: {title: {text: `${state.cosine === "f_cos" ? "f · cos θi" : "f"} (sr⁻¹)`}, type: state.scale},
  };
  const box = $("swatches");
  box.replaceChildren(...payload.colours.map((entry) => {
    const item = document.createElement("div");
    item.className = "swatch";
    const swatch = document.createElement("span");
    swatch.className = "box";
    swatch.style.background = `rgb(${entry.hue.map(encoded).join(",")})`;
    const rgb = entry.rgb.map((v) => v.toPrecision(3)).join(", ");
    item.append(swatch, `${nameOf(entry.label)}: linear sRGB (${rgb}) sr⁻¹`);
    return item;
  }));
  if (!payload.curves.length && !payload.measured) {  // no axes to read: an empty chart showed −1…6 nm
    return Plotly.react("plot-spectrum", [], {...layout, title: title("no spectral file: colours only"),
                                              xaxis: {visible: false}, yaxis: {visible: false}}, CONFIG);
  }
  return Plotly.react("plot-spectrum", traces, layout, CONFIG);
}

const DRAW = {inplane: drawInplane, hemisphere: drawHemisphere, lobe: drawLobe, halfdiff: drawHalfdiff,
              sphere: drawSphere, spectrum: drawSpectrum};

// ------------------------------------------------------------------ start

function describeSources() {
  const table = document.createElement("table");
  table.className = "files";
  table.innerHTML = "<tr><th>file</th><th>kind</th><th>material</th><th>values</th><th>what the file records</th></tr>";
  scene.sources.forEach((source, k) => {
    colours[source.label] = source.role === "truth" ? TRUTH_COLOUR : PALETTE[k % PALETTE.length];
    const row = table.insertRow();
    const key = document.createElement("span");
    key.className = "swatch-key";
    key.style.background = colours[source.label];
    row.insertCell().append(key, nameOf(source.label));
    row.insertCell().textContent = source.kind;
    row.insertCell().textContent = source.material;
    row.insertCell().textContent = source.spectral
      ? `spectral ${source.wavelength_range_nm[0]}–${source.wavelength_range_nm[1]} nm` : "RGB (linear sRGB)";
    const details = document.createElement("details");
    const lines = [...source.fast_paths, source.rgb_rule ? `colour from ${source.rgb_rule}` : "",
                   source.no_colour ? `no colour: ${source.no_colour}` : ""].filter(Boolean);
    details.innerHTML = `<summary>${lines.length ? lines.join("; ") : "no fast path"} — every metadata entry</summary>`;
    const entries = document.createElement("table");
    entries.insertRow().insertCell().textContent = source.file;
    for (const [name, value] of Object.entries(source.metadata)) {
      const entry = entries.insertRow();
      entry.insertCell().textContent = name;
      entry.insertCell().textContent = value;
    }
    details.append(entries);
    row.insertCell().append(details);
  });
  $("sources").append(table);
  if (scene.measured) {
    const m = scene.measured;
    const note = document.createElement("p");
    note.textContent = `Measurement ${m.label}: ${m.rows} samples in the plane of incidence` +
      (m.rows_out_of_plane ? ` (${m.rows_out_of_plane} out of it, not drawn)` : "") +
      `, ${m.spectral ? "spectral" : "RGB"}, at θi = ${m.theta_i.join("°, ")}° (samples at negative θi drawn at (−θi, −θr)).`;
    $("sources").append(note);
  }
}

async function start() {
  const response = await fetch("api/scene");
  scene = await response.json();
  readUrl();
  describeSources();
  for (const [name, control] of Object.entries(scene.controls)) addControl(name, control);
  for (const [name, control] of Object.entries(LOCAL)) addControl(name, control);
  for (const view of Object.keys(scene.views)) stale.add(view);  // drawn when on screen
  markStale();
  await watchVisibility();
  while (busy) await new Promise((resolve) => setTimeout(resolve, 20));
  document.body.dataset.ready = "1";
}

start().catch((error) => showStatus(`error: ${error.message}`, true));
