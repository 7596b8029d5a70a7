// SPADE sketching page: plain JS, no build step, everything from this app's /api/ and /static/.
"use strict";

const $ = (id) => document.getElementById(id);
const canvas = $("canvas");
const g = canvas.getContext("2d");

const FREEHAND_STEP_M = 0.3;
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

function drawRobot(pose) {
  const [x, y, yaw] = pose;
  const [sx, sy] = worldToScreen(x, y);
  const r = Math.max(8, state.meta.robot.radius_m / state.meta.resolution * state.view.scale);
  g.save();
  g.translate(sx, sy); g.rotate(-yaw);  // yaw counter-clockwise, screen y down
  g.beginPath(); g.moveTo(1.8 * r, 0); g.lineTo(-r, 0.9 * r); g.lineTo(-0.5 * r, 0); g.lineTo(-r, -0.9 * r); g.closePath();
  g.fillStyle = "#1f4fe0"; g.fill(); g.strokeStyle = "#fff"; g.lineWidth = 1.5; g.stroke();
  g.restore();
}

function draw() {
  if (!state.meta) return;
  const m = state.meta, v = state.view;
  g.setTransform(1, 0, 0, 1, 0, 0);
  g.fillStyle = "#888"; g.fillRect(0, 0, canvas.width, canvas.height);
  g.imageSmoothingEnabled = false;
  if (state.mapImg) g.drawImage(state.mapImg, v.ox, v.oy, m.width_px * v.scale, m.height_px * v.scale);
  if (state.showCostmap && state.costImg) g.drawImage(state.costImg, v.ox, v.oy, m.width_px * v.scale, m.height_px * v.scale);

  // the saved sketches, thin; the one picked in the list, bold
  state.saved.forEach((s) => { if (s.name !== state.selected) polyline(s.waypoints, "rgba(59,108,240,.55)", 1.5, [4, 4]); });
  const sel = state.saved.find((s) => s.name === state.selected);
  if (sel) { polyline(sel.waypoints, "#3b6cf0", 2.5, [6, 4]); sel.waypoints.forEach(([x, y]) => dot(x, y, 3, "#3b6cf0")); }

  // the current sketch and its execution
  const ex = state.execution;
  if (ex && ex.path && ex.path.length) polyline(ex.path, ex.accepted ? "#12a150" : "#d9822b", 4);
  if (ex && ex.offending && ex.offending.length) ex.offending.forEach(([x, y]) => dot(x, y, 3.5, "#e01b1b"));
  polyline(state.waypoints, "#ff8c00", 2, [5, 4]);
  const bad = new Set(ex && ex.offending_waypoints ? ex.offending_waypoints : []);
  state.waypoints.forEach(([x, y], i) => {
    const last = i === state.waypoints.length - 1;
    dot(x, y, last ? 7 : 6, bad.has(i) ? "#e01b1b" : (last ? "#0a8f3c" : "#ff8c00"), "#fff");
    const [sx, sy] = worldToScreen(x, y);
    g.fillStyle = "#fff"; g.font = "bold 9px system-ui, sans-serif"; g.textAlign = "center"; g.textBaseline = "middle";
    g.fillText(String(i + 1), sx, sy + 0.5);
  });
  g.textAlign = "start"; g.textBaseline = "alphabetic";

  // the policy
  if (state.plan && state.plan.overlay && state.overlayImg) {
    const o = state.plan.overlay;
    const [ax, ay] = worldToScreen(o.x_min, o.y_max), [bx, by] = worldToScreen(o.x_max, o.y_min);
    g.drawImage(state.overlayImg, ax, ay, bx - ax, by - ay);
    polyline([...o.window_m, o.window_m[0]], "#7a2cc9", 1.5, [4, 3]);  // the student's (rotated) window
  }
  if (state.plan && state.plan.baselines && $("show-baselines") && $("show-baselines").checked) {
    state.plan.baselines.forEach((b) => polyline(b.waypoints, b.colour || "#0aa", 2, [3, 3]));
  }
  if (state.plan && state.plan.waypoints.length) polyline(state.plan.waypoints, "#c000c0", 3);
  if (state.goal) { dot(state.goal[0], state.goal[1], 7, "#e33", "#fff"); }
  if (state.pose) drawRobot(state.pose);
  drawScaleBar();
}

// ---------------------------------------------------------------------------------------------- sketch editing
function pushHistory() { state.history.push(state.waypoints.map((p) => p.slice())); if (state.history.length > 200) state.history.shift(); }
function sketchChanged() {
  state.execution = null;
  $("save").disabled = true;
  $("result").textContent = ""; $("result").className = "result";
  $("waypoint-count").textContent = `${state.waypoints.length} waypoint${state.waypoints.length === 1 ? "" : "s"}`;
  draw();
}
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
  $("sketch-file").textContent = r.data.sketch_file;
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
           `${b.seconds.toFixed(1)} s → ${s.out_dir}${rej}`;
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
      + `lowest p ${c.min_probability.toFixed(2)}` + (c.fallback ? "; low confidence: the Nav2-like fallback path."
      : c.low_confidence ? "; LOW CONFIDENCE." : ".") : "";
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
}
function showModel() {
  const m = state.meta.model;
  $("model-info").textContent = m ? `model ${m.path} (${m.image_size[0]} px window at ${m.resolution_m} m/px)`
                                  : "no model: start with model=student.ckpt, or load one here";
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
  else if (d.kind === "move") { state.waypoints[d.index] = [x, y]; state.execution = null; $("save").disabled = true; draw(); }
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
  $("map-info").innerHTML = "";
  $("map-info").appendChild(document.createTextNode(
    `${m.map_id}: ${m.size_m[0].toFixed(1)} × ${m.size_m[1].toFixed(1)} m (${m.width_px} × ${m.height_px} cells at ` +
    `${m.resolution} m); x ${m.bounds_m.x_min.toFixed(2)}…${m.bounds_m.x_max.toFixed(2)} m, ` +
    `y ${m.bounds_m.y_min.toFixed(2)}…${m.bounds_m.y_max.toFixed(2)} m`));
  [state.mapImg, state.costImg] = await Promise.all([loadImage("/api/map.png"), loadImage("/api/costmap.png")]);
  showModel();
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
});
document.querySelectorAll("input[name=shape]").forEach((el) => el.onchange = () => { if (state.execution) sketchChanged(); });
["pose-x", "pose-y", "pose-yaw", "goal-x", "goal-y"].forEach((id) => $(id).addEventListener("change", poseFromInputs));
window.addEventListener("resize", resize);

// For scripts and the browser test: map metres <-> canvas pixels, the page's state.
window.spade = { state, worldToScreen, screenToWorld, fit, draw };
start();
