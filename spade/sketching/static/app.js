// SPADE sketching page: plain JS, no build step, everything from this app's /api/ and /static/.
"use strict";

const $ = (id) => document.getElementById(id);
const canvas = $("canvas");
const g = canvas.getContext("2d");

const FREEHAND_STEP_M = 0.3;
const OFF_MAP = "#2e3440";  // around the map: darker than any map grey (unknown cells are grey 160)
let C = {};                 // the palette (spade/utils/palette.py), from GET /api/map: C.robot, C.prediction, ...
const state = {
  meta: null,              // GET /api/map
  mapImg: null, costImg: null,
  showCostmap: false,
  view: { scale: 1, ox: 0, oy: 0 },   // screen px per map cell; screen position of the map's top-left corner
  mode: "sketch",          // sketch | policy
  waypoints: [],           // [[x, y], ...] metres
  history: [],             // undo stack of waypoint lists
  execution: null,         // last POST /api/execute answer for the current waypoints
  saved: [],               // GET /api/sketches
  selected: null,          // name of the saved sketch drawn on the map
  pose: null, goal: null,  // policy: [x, y, yaw], [x, y]
  plan: null, overlayImg: null,
  drag: null,              // current mouse gesture
};

// ---------------------------------------------------------------------------------------------- geometry
function worldToScreen(x, y) {
  const m = state.meta, v = state.view;
  return [v.ox + (x - m.origin[0]) / m.resolution * v.scale,
          v.oy + (m.height_px - (y - m.origin[1]) / m.resolution) * v.scale];
}
function screenToWorld(sx, sy) {
  const m = state.meta, v = state.view;
  return [m.origin[0] + (sx - v.ox) / v.scale * m.resolution,
          m.origin[1] + (m.height_px - (sy - v.oy) / v.scale) * m.resolution];
}
// The student's window where the sketch puts it, by the server's rule (spade.annotation.pipeline.WindowFitRule, its
// numbers served as meta.window): the robot at the first waypoint, heading towards the sketch's point heading_m
// along it; the waypoints must lie margin_m inside it. Corners in map metres; outside: indices of the waypoints
// that do not. The executed path's part of the rule is the server's alone: its verdict replaces this one once the
// sketch is executed (showFit).
function sketchWindow(points) {
  const m = state.meta, w = m.window;
  if (!points || points.length < 2) return null;
  const res = w.resolution_m, size = w.size_px, [rx, ry] = w.robot_px, margin = w.margin_m / res;
  let reach = w.heading_m, ahead = points[points.length - 1];
  for (let i = 1; i < points.length; i++) {
    const [ax, ay] = points[i - 1], [bx, by] = points[i], len = Math.hypot(bx - ax, by - ay);
    if (len >= reach && len > 0) { ahead = [ax + (bx - ax) * reach / len, ay + (by - ay) * reach / len]; break; }
    reach -= len;
  }
  const [x0, y0] = points[0];
  let fx = ahead[0] - x0, fy = ahead[1] - y0;
  const n = Math.hypot(fx, fy) || 1; fx /= n; fy /= n;
  const toMap = (u, v) => [x0 + ((u - rx) * fy + (ry - v) * fx) * res, y0 + (-(u - rx) * fx + (ry - v) * fy) * res];
  const toWindow = ([x, y]) => { const dx = x - x0, dy = y - y0; return [rx + (dx * fy - dy * fx) / res, ry - (dx * fx + dy * fy) / res]; };
  const rect = (lo, hi) => [toMap(lo, lo), toMap(hi, lo), toMap(hi, hi), toMap(lo, hi)];
  const outside = [];
  points.forEach((p, i) => {
    const [u, v] = toWindow(p);
    if (u < margin || v < margin || u > size - 1 - margin || v > size - 1 - margin) outside.push(i);
  });
  return { corners: rect(-0.5, size - 0.5), margin: rect(margin, size - 1 - margin), outside,
           heading: Math.atan2(fy, fx), size_m: size * res };
}

function canvasPoint(ev) {
  const r = canvas.getBoundingClientRect();
  return [ev.clientX - r.left, ev.clientY - r.top];
}

function fit() {
  const m = state.meta;
  const w = canvas.width, h = canvas.height;
  const scale = 0.95 * Math.min(w / m.width_px, h / m.height_px);
  state.view = { scale, ox: (w - m.width_px * scale) / 2, oy: (h - m.height_px * scale) / 2 };
  draw();
}

function resize() {
  const r = canvas.getBoundingClientRect();
  canvas.width = Math.max(1, Math.round(r.width));
  canvas.height = Math.max(1, Math.round(r.height));
  draw();
}

// ---------------------------------------------------------------------------------------------- API
async function api(method, path, body) {
  const opts = { method, headers: {} };
  if (body !== undefined) { opts.headers["Content-Type"] = "application/json"; opts.body = JSON.stringify(body); }
  const res = await fetch(path, opts);
  let data = null;
  try { data = await res.json(); } catch (e) { data = { error: `HTTP ${res.status}` }; }
  return { ok: res.ok, status: res.status, data };
}

function loadImage(src) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = reject;
    img.src = src;
  });
}

function setResult(id, cls, text) {
  const el = $(id);
  el.className = "result " + cls;
  el.textContent = text;
}

// ---------------------------------------------------------------------------------------------- drawing
function polyline(points, colour, width, dash) {
  if (!points || points.length < 2) return;
  g.save();
  g.strokeStyle = colour; g.lineWidth = width; g.lineJoin = "round"; g.lineCap = "round";
  if (dash) g.setLineDash(dash);
  g.beginPath();
  points.forEach(([x, y], i) => { const [sx, sy] = worldToScreen(x, y); i ? g.lineTo(sx, sy) : g.moveTo(sx, sy); });
  g.stroke();
  g.restore();
}

function dot(x, y, r, fill, stroke) {
  const [sx, sy] = worldToScreen(x, y);
  g.beginPath(); g.arc(sx, sy, r, 0, 2 * Math.PI);
  g.fillStyle = fill; g.fill();
  if (stroke) { g.strokeStyle = stroke; g.lineWidth = 1.5; g.stroke(); }
}

function niceLength(metres) {
  const p = Math.pow(10, Math.floor(Math.log10(metres)));
  for (const k of [1, 2, 5, 10]) if (k * p >= metres) return k * p;
  return 10 * p;
}

function drawScaleBar() {
  const m = state.meta;
  const pxPerMetre = state.view.scale / m.resolution;
  const metres = niceLength(100 / pxPerMetre);
  const len = metres * pxPerMetre;
  const x0 = 16, y0 = canvas.height - 20;
  g.save();
  g.fillStyle = "rgba(255,255,255,.85)"; g.fillRect(x0 - 8, y0 - 22, len + 70, 32);
  g.strokeStyle = "#111"; g.lineWidth = 3;
  g.beginPath(); g.moveTo(x0, y0); g.lineTo(x0 + len, y0); g.stroke();
  g.lineWidth = 2;
  g.beginPath(); g.moveTo(x0, y0 - 6); g.lineTo(x0, y0 + 4); g.moveTo(x0 + len, y0 - 6); g.lineTo(x0 + len, y0 + 4); g.stroke();
  g.fillStyle = "#111"; g.font = "12px system-ui, sans-serif";
  g.fillText(`${metres >= 1 ? metres : metres.toFixed(2)} m`, x0 + len + 8, y0 + 4);
  g.restore();
}

function drawGrid() {
  // metre grid over the map, its spacing chosen for the zoom (a line every 40 px or more), labelled at the edges
  const m = state.meta, b = m.bounds_m, pxPerMetre = state.view.scale / m.resolution;
  const step = niceLength(40 / pxPerMetre);
  const [ax, ay] = worldToScreen(b.x_min, b.y_max), [bx, by] = worldToScreen(b.x_max, b.y_min);
  g.save();
  g.beginPath(); g.rect(ax, ay, bx - ax, by - ay); g.clip();
  g.strokeStyle = "rgba(40,60,110,.18)"; g.lineWidth = 1;
  g.beginPath();
  for (let x = Math.ceil(b.x_min / step) * step; x <= b.x_max; x += step) { const [sx] = worldToScreen(x, 0); g.moveTo(Math.round(sx) + 0.5, ay); g.lineTo(Math.round(sx) + 0.5, by); }
  for (let y = Math.ceil(b.y_min / step) * step; y <= b.y_max; y += step) { const [, sy] = worldToScreen(0, y); g.moveTo(ax, Math.round(sy) + 0.5); g.lineTo(bx, Math.round(sy) + 0.5); }
  g.stroke();
  g.restore();
  g.save();
  g.strokeStyle = "#cfd6e4"; g.lineWidth = 1; g.strokeRect(ax - 0.5, ay - 0.5, bx - ax + 1, by - ay + 1);  // the map's edge
  // labels: dark text on a white halo, legible over the map, the costmap and the dark surround alike
  g.font = "bold 11px system-ui, sans-serif"; g.lineWidth = 3; g.strokeStyle = "#fff"; g.fillStyle = "#1d2330";
  g.lineJoin = "round"; g.textAlign = "center"; g.textBaseline = "top";
  const label = (v, unit) => `${+v.toFixed(2)}${unit}`;
  const text = (t, x, y) => { g.strokeText(t, x, y); g.fillText(t, x, y); };
  for (let x = Math.ceil(b.x_min / step) * step; x <= b.x_max; x += step) {
    const [sx] = worldToScreen(x, 0);
    if (sx > 40 && sx < canvas.width - 24) text(label(x, " m"), sx, 3);
  }
  g.textAlign = "left"; g.textBaseline = "middle";
  for (let y = Math.ceil(b.y_min / step) * step; y <= b.y_max; y += step) {
    const [, sy] = worldToScreen(0, y);
    if (sy > 24 && sy < canvas.height - 40) text(label(y, " m"), 3, sy);
  }
  g.restore();
  // the map frame: its origin and axes, 1 m each, where the origin is on the map
  if (b.x_min <= 0 && 0 <= b.x_max && b.y_min <= 0 && 0 <= b.y_max) {
    const [ox, oy] = worldToScreen(0, 0), len = Math.max(24, pxPerMetre);
    g.save(); g.strokeStyle = "#111"; g.fillStyle = "#111"; g.lineWidth = 2; g.font = "bold 11px system-ui, sans-serif";
    g.beginPath(); g.moveTo(ox, oy); g.lineTo(ox + len, oy); g.moveTo(ox, oy); g.lineTo(ox, oy - len); g.stroke();
    g.fillText("x", ox + len + 3, oy + 4); g.fillText("y", ox - 3, oy - len - 4);
    g.beginPath(); g.arc(ox, oy, 3, 0, 2 * Math.PI); g.fill();
    g.restore();
  }
}

function footprint() { return state.meta.footprint || state.meta.robot; }

function drawFootprint(x, y) {
  // the robot's footprint to scale (radius), its inflation dashed
  const f = footprint(), ppm = state.view.scale / state.meta.resolution, [sx, sy] = worldToScreen(x, y);
  g.save();
  g.beginPath(); g.arc(sx, sy, Math.max(2, f.radius_m * ppm), 0, 2 * Math.PI);
  g.fillStyle = hexAlpha(C.robot, 0.35); g.fill(); g.strokeStyle = C.robot; g.lineWidth = 1.5; g.stroke();
  g.beginPath(); g.arc(sx, sy, (f.radius_m + f.inflation_radius_m) * ppm, 0, 2 * Math.PI);
  g.setLineDash([3, 3]); g.strokeStyle = hexAlpha(C.robot, 0.6); g.lineWidth = 1; g.stroke();
  g.restore();
}

function hexAlpha(hex, a) {
  const v = parseInt(hex.slice(1), 16);
  return `rgba(${(v >> 16) & 255},${(v >> 8) & 255},${v & 255},${a})`;
}

function drawWindow(win, outsideCount) {
  // the student's window (solid) and the margin the sketch must keep inside it (dashed)
  polyline([...win.corners, win.corners[0]], C.window, 2);
  polyline([...win.margin, win.margin[0]], hexAlpha(C.window, 0.8), 1.2, [6, 4]);
  const top = win.corners.reduce((a, p) => (worldToScreen(...p)[1] < worldToScreen(...a)[1] ? p : a));
  let [sx, sy] = worldToScreen(...top);
  g.save(); g.font = "bold 12px system-ui, sans-serif"; g.textAlign = "center"; g.textBaseline = "bottom";
  const text = `student's window ${win.size_m.toFixed(1)} m` + (outsideCount ? ` (${outsideCount} outside)` : "");
  const w = g.measureText(text).width + 8;
  sx = Math.min(Math.max(sx, w / 2 + 4), canvas.width - w / 2 - 4); sy = Math.max(sy, 40);  // kept on the canvas
  g.fillStyle = "rgba(255,255,255,.85)"; g.fillRect(sx - w / 2, sy - 19, w, 16);
  g.fillStyle = C.window; g.fillText(text, sx, sy - 4);
  g.restore();
}

function drawLegend() {
  const items = state.mode === "policy"
    ? [["robot, its footprint and window", C.robot], ["goal", C.goal], ["plan (the student's path)", C.prediction],
       [state.plan && state.plan.overlay ? `path probability ≥ ${state.plan.overlay.threshold}` : "path probability", C.probability], ["baseline: straight line", C["baseline-straight"]],
       ["baseline: Nav2-like shortest", C["baseline-shortest"]], ["baseline: heading template", C["baseline-heading"]]]
    : [["start, footprint, student's window", C.robot], ["sketch waypoints, executed path", C.demonstration],
       ["goal (last waypoint)", C.goal], ["outside the window / rejected part", C["low-confidence"]],
       ["rejected execution", "#555"]];
  g.save(); g.font = "12px system-ui, sans-serif";
  const w = Math.max(...items.map(([t]) => g.measureText(t).width)) + 40, h = 18 * items.length + 10;
  const x0 = canvas.width - w - 10, y0 = 22;
  g.fillStyle = "rgba(255,255,255,.9)"; g.fillRect(x0, y0, w, h); g.strokeStyle = "#99a"; g.strokeRect(x0 + 0.5, y0 + 0.5, w, h);
  items.forEach(([t, c], i) => {
    const y = y0 + 14 + 18 * i;
    g.fillStyle = c; g.fillRect(x0 + 8, y - 4, 20, 6);
    g.fillStyle = "#222"; g.textBaseline = "middle"; g.fillText(t, x0 + 34, y);
  });
  g.restore();
}

function drawRobot(pose) {
  const [x, y, yaw] = pose;
  const [sx, sy] = worldToScreen(x, y);
  const r = Math.max(8, state.meta.robot.radius_m / state.meta.resolution * state.view.scale);
  g.save();
  g.translate(sx, sy); g.rotate(-yaw);  // yaw counter-clockwise, screen y down
  g.beginPath(); g.moveTo(1.8 * r, 0); g.lineTo(-r, 0.9 * r); g.lineTo(-0.5 * r, 0); g.lineTo(-r, -0.9 * r); g.closePath();
  g.fillStyle = C.robot; g.fill(); g.strokeStyle = "#fff"; g.lineWidth = 1.5; g.stroke();
  g.restore();
}

function draw() {
  if (!state.meta) return;
  const m = state.meta, v = state.view;
  g.setTransform(1, 0, 0, 1, 0, 0);
  g.fillStyle = OFF_MAP; g.fillRect(0, 0, canvas.width, canvas.height);
  g.imageSmoothingEnabled = false;
  if (state.mapImg) g.drawImage(state.mapImg, v.ox, v.oy, m.width_px * v.scale, m.height_px * v.scale);
  if (state.showCostmap && state.costImg) g.drawImage(state.costImg, v.ox, v.oy, m.width_px * v.scale, m.height_px * v.scale);
  drawGrid();

  // the saved sketches, thin; the one picked in the list, bold
  const saved = hexAlpha(C.demonstration, 0.55);
  state.saved.forEach((s) => { if (s.name !== state.selected) polyline(s.waypoints, saved, 1.5, [4, 4]); });
  const sel = state.saved.find((s) => s.name === state.selected);
  if (sel) { polyline(sel.waypoints, C.demonstration, 2.5, [6, 4]); sel.waypoints.forEach(([x, y]) => dot(x, y, 3, C.demonstration)); }

  if (state.mode === "sketch") drawSketch();

  // the policy
  if (state.plan && state.plan.overlay && state.overlayImg) {
    const o = state.plan.overlay;
    const [ax, ay] = worldToScreen(o.x_min, o.y_max), [bx, by] = worldToScreen(o.x_max, o.y_min);
    g.drawImage(state.overlayImg, ax, ay, bx - ax, by - ay);
    polyline([...o.window_m, o.window_m[0]], C.window, 1.5, [4, 3]);  // the student's (rotated) window
  }
  if (state.plan && state.plan.baselines && $("show-baselines") && $("show-baselines").checked) {
    state.plan.baselines.forEach((b) => { polyline(b.waypoints, "#fff", 5); polyline(b.waypoints, b.colour, 3, [7, 4]); });
  }
  if (state.plan && state.plan.waypoints.length) {
    polyline(state.plan.waypoints, "#0b2530", 6);  // a dark edge: cyan reads over white, magenta and the baselines
    polyline(state.plan.waypoints, C.prediction, 3.5);
  }
  if (state.goal) { dot(state.goal[0], state.goal[1], 7, C.goal, "#fff"); }
  if (state.pose) { drawFootprint(state.pose[0], state.pose[1]); drawRobot(state.pose); }
  drawScaleBar();
  drawLegend();
}

function drawSketch() {
  // the current sketch: the student's window it puts the robot in (drawn before executing), its footprint,
  // then its execution, then the waypoints, numbered from 1 like every message
  const ex = state.execution;
  const win = sketchWindow(state.waypoints);
  state.window = win;
  if (win) drawWindow(win, win.outside.length);
  if (state.waypoints.length) drawFootprint(...state.waypoints[0]);
  if (ex && ex.path && ex.path.length) polyline(ex.path, ex.accepted ? C.demonstration : "#555", 4, ex.accepted ? null : [8, 4]);
  if (ex && ex.offending && ex.offending.length) ex.offending.forEach(([x, y]) => dot(x, y, 3.5, C["low-confidence"], "#000"));
  polyline(state.waypoints, C.demonstration, 2, [5, 4]);
  const bad = new Set([...(ex && ex.offending_waypoints ? ex.offending_waypoints : []), ...(win ? win.outside : [])]);
  state.waypoints.forEach(([x, y], i) => {
    const last = i === state.waypoints.length - 1;
    if (bad.has(i)) { const [sx, sy] = worldToScreen(x, y); g.beginPath(); g.arc(sx, sy, 11, 0, 2 * Math.PI); g.lineWidth = 4; g.strokeStyle = C["low-confidence"]; g.stroke(); }
    dot(x, y, last ? 8 : 7, i === 0 ? C.robot : (last ? C.goal : C.demonstration), bad.has(i) ? "#000" : "#fff");
    const [sx, sy] = worldToScreen(x, y);
    g.fillStyle = "#fff"; g.font = "bold 10px system-ui, sans-serif"; g.textAlign = "center"; g.textBaseline = "middle";
    g.fillText(String(i + 1), sx, sy + 0.5);
  });
  g.textAlign = "start"; g.textBaseline = "alphabetic";
}

function showFit() {
  // the live verdict of the window fit, by the server's rule; once the sketch is executed, the server's own verdict
  // (which also checks the executed path), so that the two never disagree on screen
  const el = $("window-fit"), win = sketchWindow(state.waypoints), w = state.meta.window;
  if (!win) { el.textContent = ""; el.className = "fit"; delete el.dataset.fits; delete el.dataset.source; return; }
  const served = state.execution && state.execution.window;
  const outside = served ? served.outside_waypoints : win.outside;
  const pathOutside = served ? served.outside_points : 0;
  if (!outside.length && !pathOutside) {
    el.textContent = `Fits the student's window (${win.size_m.toFixed(1)} m, every waypoint ${w.margin_m} m inside it).`;
    el.className = "fit fits"; el.dataset.fits = "1";
  } else if (outside.length) {
    const named = outside.map((i) => `#${i + 1}`).join(", ");
    el.textContent = `Waypoint${outside.length > 1 ? "s" : ""} ${named} outside the student's window ` +
                     `(keep them ${w.margin_m} m inside the blue frame): sketch a shorter manoeuvre.`;
    el.className = "fit outside"; el.dataset.fits = "0";
  } else {
    el.textContent = `The executed path leaves the student's window (${pathOutside} points less than ` +
                     `${Math.max(0, w.path_margin_m - w.tolerance_m).toFixed(2)} m inside it): move the waypoints ` +
                     "near the frame inwards.";
    el.className = "fit outside"; el.dataset.fits = "0";
  }
  el.dataset.source = served ? "server" : "page";
  el.dataset.outside = JSON.stringify(outside);
}

// ---------------------------------------------------------------------------------------------- sketch editing
function pushHistory() { state.history.push(state.waypoints.map((p) => p.slice())); if (state.history.length > 200) state.history.shift(); }
function sketchChanged() {
  state.execution = null;
  $("save").disabled = true;
  $("result").textContent = ""; $("result").className = "result";
  $("waypoint-count").textContent = `${state.waypoints.length} waypoint${state.waypoints.length === 1 ? "" : "s"}`;
  showFit();
  enableExecute();
  draw();
}
function enableExecute() {
  // Execute needs a sketch: at least 2 waypoints (the start, the goal last)
  const n = state.waypoints.length;
  $("execute").disabled = n < 2;
  $("execute").title = n < 2 ? `click ${2 - n} more waypoint${n === 1 ? "" : "s"} on the map first (the goal last)` : "";
}
function setSketch(points) { pushHistory(); state.waypoints = points.map((p) => p.slice()); sketchChanged(); }
function undo() { if (state.history.length) { state.waypoints = state.history.pop(); sketchChanged(); } }
function clearSketch() { if (state.waypoints.length) { pushHistory(); state.waypoints = []; sketchChanged(); } }

function hitWaypoint(sx, sy) {
  for (let i = state.waypoints.length - 1; i >= 0; i--) {
    const [px, py] = worldToScreen(...state.waypoints[i]);
    if (Math.hypot(px - sx, py - sy) <= 9) return i;
  }
  return -1;
}

function shape() { return document.querySelector("input[name=shape]:checked").value; }

async function execute() {
  if (state.waypoints.length < 2) { setResult("result", "error", "Click at least 2 waypoints first."); return; }
  setResult("result", "info", "executing…");
  const r = await api("POST", "/api/execute", { shape: shape(), waypoints: state.waypoints });
  if (!r.ok) { state.execution = null; setResult("result", "error", r.data.error); draw(); return; }
  state.execution = r.data;
  showFit();
  $("save").disabled = !r.data.accepted;
  setResult("result", r.data.accepted ? "accepted" : "rejected",
            `${r.data.accepted ? "Accepted" : "Rejected"}: ${r.data.message.replace(/^(accepted|rejected[^:]*): /, "")}` +
            ` (${r.data.execute_ms} ms)`);
  draw();
}

async function save() {
  const body = { shape: shape(), waypoints: state.waypoints };
  const name = $("sketch-name").value.trim();
  if (name) body.name = name;
  const r = await api("POST", "/api/sketches", body);
  if (!r.ok) { setResult("result", "error", r.data.error); return; }
  setResult("result", "accepted", `Saved as ${r.data.saved.name} (${r.data.count} saved, ${r.data.save_ms} ms).`);
  state.selected = r.data.saved.name;
  pushHistory();
  state.waypoints = []; state.execution = null; $("save").disabled = true; $("sketch-name").value = "";
  $("waypoint-count").textContent = "0 waypoints";
  showFit();
  enableExecute();
  await refreshSaved();
}

async function refreshSaved() {
  const r = await api("GET", "/api/sketches");
  if (!r.ok) return;
  const key = JSON.stringify([r.data.sketches, state.selected]);
  if (key === state.savedKey) return;  // unchanged: keep the table (and the button under the mouse)
  state.savedKey = key;
  state.saved = r.data.sketches;
  $("saved-count").textContent = `(${state.saved.length})`;
  $("sketch-file").textContent = r.data.sketch_file_shown || r.data.sketch_file;
  const body = $("saved").querySelector("tbody");
  body.innerHTML = "";
  state.saved.forEach((s) => {
    const tr = document.createElement("tr");
    tr.dataset.name = s.name;
    if (s.name === state.selected) tr.className = "selected";
    const len = s.executed && s.executed.length_m !== undefined ? `${s.executed.length_m.toFixed(2)} m` : "";
    tr.innerHTML = `<td class="name"></td><td>${s.shape}</td><td>${len}</td>` +
                   `<td><button type="button" class="show">show</button></td>` +
                   `<td><button type="button" class="delete">delete</button></td>`;
    tr.querySelector(".name").textContent = s.name;
    tr.querySelector(".show").onclick = () => { state.selected = state.selected === s.name ? null : s.name; refreshSaved(); draw(); };
    tr.querySelector(".delete").onclick = async () => {
      if (!confirm(`Delete the saved sketch ${s.name}?`)) return;
      const d = await api("DELETE", `/api/sketches/${encodeURIComponent(s.name)}`);
      if (!d.ok) setResult("result", "error", d.data.error);
      if (state.selected === s.name) state.selected = null;
      await refreshSaved(); draw();
    };
    body.appendChild(tr);
  });
  draw();
}

// ---------------------------------------------------------------------------------------------- dataset
function showBuild(b) {
  $("build-progress").value = b.progress;
  let text = `${b.state}: ${b.instances} instances from ${b.sketches} sketches, ${b.seconds.toFixed(1)} s`;
  if (b.state === "done") {
    const s = b.summary;
    const rej = Object.keys(s.rejections || {}).length ? `; rejected: ${JSON.stringify(s.rejections)}` : "";
    text = `done: ${s.instances} instances from ${s.scenarios_accepted} of ${s.scenarios_tried} sketches in ` +
           `${b.seconds.toFixed(1)} s → ${s.out_dir_shown || s.out_dir}${rej}`;
  }
  if (b.state === "failed") text = `failed: ${b.error}`;
  $("build-status").textContent = text;
  $("build-status").dataset.state = b.state;
}

async function build() {
  $("build").disabled = true;
  const r = await api("POST", "/api/build", {});
  if (!r.ok) { $("build-status").textContent = r.data.error; $("build-status").dataset.state = "error"; $("build").disabled = false; return; }
  let b = r.data;
  showBuild(b);
  while (b.state === "running") {
    await new Promise((ok) => setTimeout(ok, 250));
    const s = await api("GET", "/api/build");
    if (!s.ok) break;
    b = s.data;
    showBuild(b);
  }
  if (b.state === "done") {
    const img = $("build-preview");
    img.src = `/api/build/preview.png?t=${Date.now()}`;
    img.hidden = false;
  }
  $("build").disabled = false;
}

// ---------------------------------------------------------------------------------------------- policy
function poseFromInputs() {
  const x = parseFloat($("pose-x").value), y = parseFloat($("pose-y").value);
  const yaw = (parseFloat($("pose-yaw").value) || 0) * Math.PI / 180;
  state.pose = Number.isFinite(x) && Number.isFinite(y) ? [x, y, yaw] : null;
  const gx = parseFloat($("goal-x").value), gy = parseFloat($("goal-y").value);
  state.goal = Number.isFinite(gx) && Number.isFinite(gy) ? [gx, gy] : null;
  draw();
}
function poseToInputs() {
  if (state.pose) {
    $("pose-x").value = state.pose[0].toFixed(2); $("pose-y").value = state.pose[1].toFixed(2);
    $("pose-yaw").value = (state.pose[2] * 180 / Math.PI).toFixed(0);
  }
  if (state.goal) { $("goal-x").value = state.goal[0].toFixed(2); $("goal-y").value = state.goal[1].toFixed(2); }
}

async function plan() {
  poseFromInputs();
  if (!state.pose || !state.goal) { setResult("plan-result", "error", "Place the robot and the goal first."); return; }
  setResult("plan-result", "info", "planning…");
  const r = await api("POST", "/api/plan", { pose: state.pose, goal: state.goal });
  if (!r.ok) { state.plan = null; setResult("plan-result", "error", r.data.error); draw(); return; }
  state.plan = r.data;
  state.overlayImg = r.data.overlay ? await loadImage(r.data.overlay.png) : null;
  const p = r.data;
  const c = p.confidence;
  const confidence = c ? ` Decoded by ${p.decode}: ${(100 * c.low_share).toFixed(0)} % of it through p < 0.5, `
      + `lowest p ${c.min_probability.toFixed(2)}` + (c.advice ? `. ${c.advice[0].toUpperCase()}${c.advice.slice(1)}.` : ".")
      : "";
  setResult("plan-result", p.success ? (c && c.low_confidence ? "failure" : "success") : "failure",
            p.success ? `Path of ${p.length_m.toFixed(2)} m, ${p.waypoints.length} waypoints, ${p.latency_ms} ms.${confidence}`
                      : `No path (${p.code}): ${p.reason} (${p.latency_ms} ms).`);
  const img = $("plan-probability");
  const reveal = () => $("policy-section").scrollIntoView({ block: "end" });
  if (p.probability) { img.onload = reveal; img.src = p.probability; img.hidden = false; } else { img.hidden = true; }
  const hasBaselines = p.baselines && p.baselines.length;
  $("baselines").innerHTML = hasBaselines ? `<label><input type="checkbox" id="show-baselines" checked> classical baselines (${p.baselines[0].all_ms} ms)</label>` : "";
  if (hasBaselines) $("show-baselines").onchange = draw;
  reveal();
  (p.baselines || []).forEach((b) => {
    const div = document.createElement("div");
    div.innerHTML = `<span class="swatch" style="background:${b.colour || "#0aa"}"></span>`;
    div.appendChild(document.createTextNode(`baseline ${b.name}: ${b.success ? b.length_m.toFixed(2) + " m" : "no path"}`));
    $("baselines").appendChild(div);
  });
  draw();
}

async function loadModel() {
  const r = await api("POST", "/api/model", { path: $("model-path").value.trim() });
  if (!r.ok) { setResult("plan-result", "error", r.data.error); return; }
  state.meta.model = r.data.model;
  showModel();
  draw();
}
function showModel() {
  const m = state.meta.model;
  const f = m && m.footprint;
  const fp = f && f.source === "model" ? `; trained for a robot radius ${f.radius_m} m + inflation ${f.inflation_radius_m} m` +
      (f.assumed ? " (assumed: the file predates footprint records)" : "") +
      (f.differs_from_settings ? `, NOT the ${f.settings.radius_m} m + ${f.settings.inflation_radius_m} m these sketches assume` : "") : "";
  $("model-info").textContent = m ? `model ${m.path_shown || m.path} (${m.image_size[0]} px window at ${m.resolution_m} m/px${fp})`
                                  : "no model: start with model=student.ckpt, or load one here";
  if (f) state.meta.footprint = f;
  $("plan").disabled = !m;
}

// ---------------------------------------------------------------------------------------------- mouse
canvas.addEventListener("mousedown", (ev) => {
  if (!state.meta) return;
  const [sx, sy] = canvasPoint(ev);
  const pan = ev.button === 1 || ev.button === 2 || ev.shiftKey;
  let kind = "click";
  let index = -1;
  if (pan) kind = "pan";
  else if (state.mode === "sketch" && ev.altKey) { kind = "freehand"; pushHistory(); state.waypoints.push(screenToWorld(sx, sy)); sketchChanged(); }
  else if (state.mode === "sketch" && (index = hitWaypoint(sx, sy)) >= 0) { kind = "move"; pushHistory(); }
  else if (state.mode === "policy" && (!state.pose || state.placing !== "goal")) kind = "pose";
  state.drag = { kind, index, sx, sy, moved: false, ox: state.view.ox, oy: state.view.oy };
  if (kind === "pose") { const [x, y] = screenToWorld(sx, sy); state.pose = [x, y, state.pose ? state.pose[2] : 0]; poseToInputs(); draw(); }
  ev.preventDefault();
});

window.addEventListener("mousemove", (ev) => {
  if (!state.meta) return;
  const [sx, sy] = canvasPoint(ev);
  const [x, y] = screenToWorld(sx, sy);
  $("cursor").textContent = `x ${x.toFixed(2)} m, y ${y.toFixed(2)} m`;
  const d = state.drag;
  if (!d) return;
  if (Math.hypot(sx - d.sx, sy - d.sy) > 4) d.moved = true;
  if (d.kind === "click" && d.moved) d.kind = "pan";
  if (d.kind === "pan") { state.view.ox = d.ox + sx - d.sx; state.view.oy = d.oy + sy - d.sy; draw(); }
  else if (d.kind === "freehand") {  // a waypoint every FREEHAND_STEP_M of the drag
    const last = state.waypoints[state.waypoints.length - 1];
    if (Math.hypot(x - last[0], y - last[1]) >= FREEHAND_STEP_M) { state.waypoints.push([x, y]); sketchChanged(); }
  }
  else if (d.kind === "move") { state.waypoints[d.index] = [x, y]; state.execution = null; $("save").disabled = true; showFit(); draw(); }
  else if (d.kind === "pose" && d.moved) { state.pose[2] = Math.atan2(-(sy - d.sy), sx - d.sx); poseToInputs(); draw(); }
});

window.addEventListener("mouseup", (ev) => {
  const d = state.drag;
  state.drag = null;
  if (!d || !state.meta) return;
  const [x, y] = screenToWorld(d.sx, d.sy);
  if (d.kind === "click" && !d.moved) {
    if (state.mode === "sketch") { pushHistory(); state.waypoints.push([x, y]); sketchChanged(); }
    else { state.goal = [x, y]; state.placing = "pose"; poseToInputs(); draw(); }
  } else if (d.kind === "move" || d.kind === "freehand") {
    sketchChanged();
  } else if (d.kind === "pose") {
    state.placing = "goal"; poseToInputs(); draw();
  }
});

canvas.addEventListener("contextmenu", (ev) => ev.preventDefault());
canvas.addEventListener("wheel", (ev) => {
  if (!state.meta) return;
  ev.preventDefault();
  const [sx, sy] = canvasPoint(ev);
  const f = Math.exp(-ev.deltaY * 0.0015);
  const v = state.view;
  v.ox = sx - (sx - v.ox) * f; v.oy = sy - (sy - v.oy) * f; v.scale *= f;
  draw();
}, { passive: false });

window.addEventListener("keydown", (ev) => {
  if (ev.target.tagName === "INPUT") return;
  if ((ev.ctrlKey || ev.metaKey) && ev.key === "z") { ev.preventDefault(); undo(); }
});

// ---------------------------------------------------------------------------------------------- start
async function start() {
  const r = await api("GET", "/api/map");
  if (!r.ok) { $("map-info").textContent = r.data.error; return; }
  state.meta = r.data;
  const m = state.meta;
  C = m.palette;  // the palette as CSS custom properties too (--spade-robot, ...), for the panel's swatches
  Object.entries(C).forEach(([k, v]) => document.documentElement.style.setProperty(`--spade-${k}`, v));
  $("map-info").innerHTML = "";
  $("map-info").appendChild(document.createTextNode(
    `${m.map_id}: ${m.size_m[0].toFixed(1)} × ${m.size_m[1].toFixed(1)} m (${m.width_px} × ${m.height_px} cells at ` +
    `${m.resolution} m); x ${m.bounds_m.x_min.toFixed(2)}…${m.bounds_m.x_max.toFixed(2)} m, ` +
    `y ${m.bounds_m.y_min.toFixed(2)}…${m.bounds_m.y_max.toFixed(2)} m`));
  [state.mapImg, state.costImg] = await Promise.all([loadImage("/api/map.png"), loadImage("/api/costmap.png")]);
  showModel();
  enableExecute();
  resize();
  fit();
  await refreshSaved();
  setInterval(() => { if (!document.hidden) refreshSaved(); }, 2000);  // other tabs' and scripts' saves
  document.body.dataset.ready = "1";
}

$("costmap-toggle").onchange = (ev) => { state.showCostmap = ev.target.checked; draw(); };
$("fit").onclick = fit;
$("undo").onclick = undo;
$("clear").onclick = clearSketch;
$("execute").onclick = execute;
$("save").onclick = save;
$("build").onclick = build;
$("plan").onclick = plan;
$("load-model").onclick = loadModel;
document.querySelectorAll("input[name=mode]").forEach((el) => el.onchange = () => {
  state.mode = document.querySelector("input[name=mode]:checked").value;
  canvas.style.cursor = state.mode === "policy" ? "cell" : "crosshair";
  draw();
});
document.querySelectorAll("input[name=shape]").forEach((el) => el.onchange = () => { if (state.execution) sketchChanged(); });
["pose-x", "pose-y", "pose-yaw", "goal-x", "goal-y"].forEach((id) => $(id).addEventListener("change", poseFromInputs));
window.addEventListener("resize", resize);

// For scripts and the browser test: map metres <-> canvas pixels, the page's state.
window.spade = { state, worldToScreen, screenToWorld, fit, draw, sketchWindow, setSketch };
start();
