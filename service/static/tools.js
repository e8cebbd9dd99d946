// depthruler web page: the measuring tools. Distance is the two-point segment app.js measures
// (POST /api/measure); path, area, height and box are shapes (POST /api/shapes, the contract in
// docs/api): points collected per tool with undo of the last one, a Measure action that ends a
// path or an area, the answer drawn on the frozen frame from the service's draw_px, and the result
// card with the value, its 95 % interval and the verdict (the box: its three dimensions).
//
// Loaded before app.js, in the same global scope: its functions use app.js's state, api, draw
// helpers and formatting when called, app.js calls them where the tool decides (placing, drawing,
// the card, the history rows, reopening), and app.js's start-up calls initTools().
"use strict";

// Per tool: how many points it takes (max: more start a new one), whether it measures as soon as
// it has them (auto) or waits for Measure, its key and what the hint says.
const TOOLS = {
  distance: { label: "Distance", key: "l", min: 2, max: 2, auto: true,
    hint: "Place two points to measure. Drag a handle to adjust." },
  path: { label: "Path", key: "p", min: 2, max: Infinity, auto: false,
    hint: "Place the path's points in order, then Measure (Enter). Backspace takes back the last one." },
  area: { label: "Area", key: "a", min: 3, max: Infinity, auto: false,
    hint: "Place the corners in order around the area (3 or more), then Measure (Enter)." },
  height: { label: "Height", key: "h", min: 1, max: 1, auto: true,
    hint: "Place one point on the object's top: its height above the surface it stands on." },
  box: { label: "Box", key: "b", min: 1, max: 1, auto: true,
    hint: "Place one point on the box's top face: its length, width and height." },
};
const SHAPE_COLOR = "#ffc94d";
const BASE_COLOR = "#7fd1ff"; // the box's base and the foot of a height: on the supporting plane
const DIMENSIONS = ["Length", "Width", "Height"];

const toolSpec = () => TOOLS[state.tool];
const isShapeTool = () => state.tool !== "distance";
const isShape = (m) => !!m && !!m.kind && m.kind !== "segment";
const enoughPoints = () => state.points.length >= toolSpec().min;

// ---- choosing a tool ------------------------------------------------------------------------------
// Show `kind` as the tool without touching the points (a reopened measurement brings its own).
function applyTool(kind) {
  state.tool = kind;
  for (const b of document.querySelectorAll("#tools [data-tool]")) {
    const on = b.dataset.tool === kind;
    b.classList.toggle("active", on);
    b.setAttribute("aria-pressed", on ? "true" : "false");
  }
  canvas.dataset.tool = kind;
  $("result-title").textContent = TOOLS[kind].label;
  showToolButtons();
}

function setTool(kind) {
  if (!(kind in TOOLS) || kind === state.tool) return;
  clearPoints();
  applyTool(kind);
  $("hint").textContent = toolSpec().hint;
}

// Undo point: while there is a point; Measure: for a path or an area, once it has enough points.
function showToolButtons() {
  const spec = toolSpec();
  $("undo-point").disabled = state.points.length === 0;
  const m = $("shape-measure");
  m.classList.toggle("hidden", spec.auto);
  m.disabled = !enoughPoints() || (!!state.result && !state.dirty);
  m.textContent = `Measure ${spec.label.toLowerCase()}`;
}

// ---- placing points -------------------------------------------------------------------------------
// A press near a placed point grabs it: the distance's two ends once both are there, any shape point.
function canGrab() {
  return isShapeTool() ? state.points.length > 0 : state.points.length === 2;
}

// A new press elsewhere starts a new measurement when the tool has all its points, or its answer is shown.
function startsAgain() {
  if (!isShapeTool()) return state.points.length >= 2;
  return state.points.length >= toolSpec().max || (!!state.result && !state.dirty);
}

// A new point was placed: measure when the tool has what it needs, else say what comes next.
function pointPlaced() {
  showToolButtons();
  const spec = toolSpec(), n = state.points.length;
  if (spec.auto && n >= spec.max) { measureTool(null); return; }
  if (!isShapeTool()) { $("hint").textContent = "Now place the second point (Esc cancels)."; return; }
  const more = spec.min - n;
  $("hint").textContent = more > 0
    ? `${n} point${n === 1 ? "" : "s"}: place ${more} more (Backspace takes back the last one).`
    : `${n} points: place more, or Measure (Enter) to end the ${spec.label.toLowerCase()}.`;
}

// A placed point was dragged: a measured shape is measured again, replacing its history entry.
function pointMoved() {
  if (!isShapeTool()) { measure(true); return; }
  if (state.result) measureTool(state.result.id);
  else { state.dirty = true; showToolButtons(); }
}

// Measure what the tool holds; `previous`: the history entry the answer replaces (an adjustment).
function measureTool(previous) {
  if (!isShapeTool()) return measure(previous !== null);
  return measureShape(previous);
}

// Measure again with other options (method): the shape on screen, replacing its entry.
function remeasure() {
  if (!isShapeTool()) { if (state.points.length === 2) measure(true); return; }
  if (state.result) measureShape(state.result.id);
}

// Take back the last point. A path or area that still has enough is measured again (replacing its
// history entry, as a drag does); otherwise the answer leaves the screen and its entry stays stored.
function undoPoint() {
  if (state.press || !state.points.length) return;
  const shown = state.result;
  state.points.pop();
  state.pointerTypes.length = Math.min(state.pointerTypes.length, state.points.length);
  state.active = Math.max(0, Math.min(state.active, state.points.length - 1));
  state.seq++; // an answer still on its way is for the old points
  state.result = null;
  state.saved = null;
  showResult(null);
  if (shown && isShapeTool() && !toolSpec().auto && enoughPoints()) measureShape(shown.id);
  else {
    state.dirty = state.points.length > 0;
    $("hint").textContent = state.points.length ? `${state.points.length} point${state.points.length === 1 ? "" : "s"} left.` : toolSpec().hint;
  }
  showToolButtons();
  draw();
}

// The keyboard's way to place a point: near the last one (or in the middle), the arrows then move it.
async function keyboardAddPoint() {
  if (!state.frame) return;
  if (state.mode !== "frozen" && !(await freeze())) return;
  if (startsAgain()) { state.points = []; state.result = null; showResult(null); }
  const last = state.points[state.points.length - 1];
  const w = canvas.width, h = canvas.height;
  const p = last ? [Math.min(w - 1, last[0] + Math.round(w / 10)), last[1]] : [Math.round(w / 2), Math.round(h / 2)];
  state.points.push(p);
  state.pointerTypes[state.points.length - 1] = "mouse";
  state.active = state.points.length - 1;
  state.dirty = true;
  state.nudging = true;
  keepVisible(p);
  queryDepth(p);
  $("hint").textContent = toolSpec().auto
    ? "Arrows move the point (Shift: 10 px), Enter measures."
    : "Arrows move the blue point (Shift: 10 px), Shift+Enter adds one, Enter measures.";
  showToolButtons();
  draw();
}

// Enter on the image with a shape tool: add a point while there are too few (or with Shift), else measure.
function shapeEnter(shift) {
  if (shift || !enoughPoints()) { keyboardAddPoint(); return; }
  if (state.dirty || !state.result) { state.nudging = false; measureShape(state.result ? state.result.id : null); }
}

// ---- measuring a shape ----------------------------------------------------------------------------
async function measureShape(previous) {
  if (!state.frame || !enoughPoints()) return;
  await optionsReady;
  if (state.mode !== "frozen" && !(await freeze())) return;
  const body = { frame_id: state.frame.id, kind: state.tool, points: state.points.map((p) => p.slice()), on: null,
    options: { method: state.method, click_px: clickPx() } };
  await submit("api/shapes", body, previous, {
    done: () => { $("hint").textContent = "Drag a point to adjust; a press elsewhere starts a new one."; },
    failed: () => { state.dirty = true; $("hint").textContent = toolSpec().hint; },
    changed: showToolButtons,
  });
}

// ---- formatting -----------------------------------------------------------------------------------
// An area in the page's unit squared ("1.000 m²", "1250 cm²").
function fmtArea(m2, withUnit = true) {
  if (m2 === null || m2 === undefined || !isFinite(m2)) return "—";
  const [k, dec] = UNITS[state.units];
  return (m2 * k * k).toFixed(dec) + (withUnit ? ` ${state.units}²` : "");
}

// A small area (an uncertainty): cm² under 0.01 m² when the page is in metres, one or two digits.
function fmtSmallArea(m2) {
  let unit = state.units;
  if (unit === "m") unit = m2 < 0.01 ? "cm" : "m";
  const v = m2 * UNITS[unit][0] ** 2;
  if (!(v > 0)) return `0 ${unit}²`;
  const mag = Math.floor(Math.log10(v));
  const digits = Math.max(0, -(mag - (v / 10 ** mag < 2 ? 1 : 0)));
  return `${v.toFixed(Math.min(6, digits))} ${unit}²`;
}

const fmtValue = (v, unit, withUnit = true) => (unit === "m2" ? fmtArea(v, withUnit) : fmt(v, withUnit));
const fmtHalf = (v, unit) => (unit === "m2" ? fmtSmallArea(v) : fmtSmall(v));

// "0.750 m ± 4 mm" around the value when the interval is symmetric enough, else "v (lo – hi)".
function fmtShapeInterval(value, interval, sigma, unit) {
  let lo, hi;
  if (Array.isArray(interval) && interval.length === 2 && interval.every((v) => v !== null && isFinite(v))) [lo, hi] = interval;
  else if (sigma !== null && sigma !== undefined && isFinite(sigma) && value !== null) [lo, hi] = [value - 1.96 * sigma, value + 1.96 * sigma];
  else return { text: `${fmtValue(value, unit)} · uncertainty unknown`, lo: null, hi: null };
  const half = (hi - lo) / 2, mid = (hi + lo) / 2;
  const text = value !== null && Math.abs(mid - value) <= 0.1 * half + 1e-12
    ? `${fmtValue(value, unit)} ± ${fmtHalf(half, unit)}`
    : `${fmtValue(value, unit)} (${fmtValue(lo, unit, false)} – ${fmtValue(hi, unit)})`;
  return { text, lo, hi };
}

// The answer in a few characters: "0.512 × 0.401 × 0.598 m" for a box, the value for the others.
function shapeValueText(m) {
  if (m.kind === "box") {
    const dims = m.dimensions_m;
    if (!Array.isArray(dims) || dims.some((v) => v === null)) return "—";
    return `${dims.map((v) => fmt(v, false)).join(" × ")} ${state.units}`;
  }
  return fmtValue(m.value, m.unit);
}

// A history row's summary, with its interval where it has one.
function shapeSummary(m) {
  if (m.kind === "box") return shapeValueText(m);
  return fmtShapeInterval(m.value, m.interval, m.uncertainty, m.unit).text;
}

function kindLabel(m) {
  return isShape(m) ? TOOLS[m.kind].label.toLowerCase() : "distance";
}

// ---- the result card ------------------------------------------------------------------------------
// The card's shape parts. Returns true when `res` is a shape (the card is done), false for a segment
// or nothing, after hiding what only shapes show.
function showShapeCard(res) {
  const dims = $("dims");
  const d = $("distance");
  d.dataset.kind = res ? kindLabel(res) : "";
  if (!isShape(res)) {
    dims.classList.add("hidden");
    dims.replaceChildren();
    d.dataset.value = "";
    $("result-title").textContent = toolSpec().label;
    return false;
  }
  $("result-title").textContent = TOOLS[res.kind].label;
  d.textContent = shapeValueText(res);
  d.dataset.id = String(res.id);
  d.dataset.value = res.value === null || res.value === undefined ? "" : String(res.value);
  d.dataset.metres = res.unit === "m" && res.value !== null ? String(res.value) : "";
  const ivEl = $("interval");
  if (res.kind === "box") {
    ivEl.textContent = "length × width × height";
    ivEl.dataset.low = ivEl.dataset.high = "";
    dims.replaceChildren(...DIMENSIONS.map((name, i) => dimensionRow(res, name, i)));
    dims.classList.remove("hidden");
  } else {
    const iv = fmtShapeInterval(res.value, res.interval, res.uncertainty, res.unit);
    ivEl.textContent = iv.text + (iv.lo === null ? "" : " · 95 % interval");
    ivEl.dataset.low = iv.lo === null ? "" : String(iv.lo);
    ivEl.dataset.high = iv.hi === null ? "" : String(iv.hi);
    dims.replaceChildren(...legRows(res));
    dims.classList.toggle("hidden", !dims.children.length);
  }
  showVerdict(res.quality, (res.reasons || []).map(String), SHAPE_ADVICE, "Look at the shape in the depth view and measure again.");
  $("ends").replaceChildren();
  const core = res.result || {};
  $("r-method").textContent = (res.options && res.options.method) || res.method || "—";
  $("r-fit").textContent = res.kind;
  $("r-samples").textContent = core.n_top_px ? `${core.n_top_px} px of the top face` : "—";
  $("r-basic").textContent = "—";
  $("r-sigma").textContent = res.kind === "box"
    ? (res.dimension_sigmas_m || []).map((v) => (v === null ? "—" : fmtSmall(v))).join(" / ")
    : res.uncertainty === null || res.uncertainty === undefined ? "—" : fmtHalf(res.uncertainty, res.unit);
  $("r-frames").textContent = "1";
  $("r-time").textContent = isFinite(core.elapsed_ms) ? `${core.elapsed_ms.toFixed(1)} ms` : "—";
  $("warnings").replaceChildren();
  return true;
}

// One of the box's dimensions: "Length 0.512 m ± 4 mm", its value and interval in data attributes.
function dimensionRow(res, name, i) {
  const v = res.dimensions_m ? res.dimensions_m[i] : null;
  const ivs = res.dimension_intervals_m ? res.dimension_intervals_m[i] : null;
  const sigma = res.dimension_sigmas_m ? res.dimension_sigmas_m[i] : null;
  const iv = fmtShapeInterval(v, ivs, sigma, "m");
  const row = document.createElement("div");
  row.className = "dim";
  row.dataset.name = name.toLowerCase();
  row.dataset.metres = v === null ? "" : String(v);
  row.dataset.low = iv.lo === null ? "" : String(iv.lo);
  row.dataset.high = iv.hi === null ? "" : String(iv.hi);
  row.innerHTML = `<b></b> <span class="dim-value"></span>`;
  row.querySelector("b").textContent = name;
  row.querySelector(".dim-value").textContent = iv.text;
  return row;
}

// A path's legs, each with its one sigma.
function legRows(res) {
  const core = res.result || {};
  if (res.kind !== "path" || !Array.isArray(core.parts)) return [];
  return core.parts.map((v, i) => {
    const row = document.createElement("div");
    row.className = "dim";
    row.dataset.metres = v === null ? "" : String(v);
    const s = core.part_sigmas && core.part_sigmas[i];
    row.textContent = `leg ${i + 1}: ${fmt(v)}${s ? " ± " + fmtSmall(1.96 * s) : ""}`;
    return row;
  });
}

// What a shape verdict's reason means for the person, and what to do (the core's phrases in measure/).
const SHAPE_ADVICE = [
  [/colour image/i, "A side of the top does not show in the image: light the box so its top stands out from its sides and the floor."],
  [/top face|not a box|box top/i, "Click the middle of the box's top face, with the whole top in view."],
  [/border|cut|outside/i, "Step back or turn so the whole object is inside the image."],
  [/hidden|occlu|in front/i, "Move so nothing stands in front of the box's faces."],
  [/rectang|parallel|tilt/i, "The top does not look like a box's: check it in the depth view, or measure it as an area."],
  [/plane|level|surface|flat/i, "Keep the points on one flat surface; for a height, click the surface it stands on in view."],
  [/few|valid|depth|hole|missing/i, "Move closer or add light and texture so the surface has depth."],
  [/uncertainty|far|distance|range/i, "Move closer: the depth error grows with the square of the distance."],
];

// ---- drawing --------------------------------------------------------------------------------------
function strokePath(c, pts, s, color, width, closed, dash) {
  if (pts.length < 2) return;
  c.save();
  c.lineCap = c.lineJoin = "round";
  if (dash) c.setLineDash(dash.map((v) => v * s));
  for (const [style, w] of [["rgba(0,0,0,.65)", width + 2.8], [color, width]]) {
    c.strokeStyle = style;
    c.lineWidth = w * s;
    c.beginPath();
    c.moveTo(...pts[0]);
    for (const p of pts.slice(1)) c.lineTo(...p);
    if (closed) c.closePath();
    c.stroke();
  }
  c.restore();
}

function fillPolygon(c, pts, color) {
  if (pts.length < 3) return;
  c.save();
  c.fillStyle = color;
  c.beginPath();
  c.moveTo(...pts[0]);
  for (const p of pts.slice(1)) c.lineTo(...p);
  c.closePath();
  c.fill();
  c.restore();
}

// The points being collected: a path's polyline, an area's polygon (closing edge dashed).
function drawCollecting(c, pts, s) {
  if (state.tool === "path") strokePath(c, pts, s, SHAPE_COLOR, 2.2, false);
  if (state.tool === "area") {
    fillPolygon(c, pts, "rgba(255,201,77,.14)");
    strokePath(c, pts, s, SHAPE_COLOR, 2.2, false);
    if (pts.length >= 3) strokePath(c, [pts[pts.length - 1], pts[0]], s, SHAPE_COLOR, 1.6, false, [6, 5]);
  }
}

// A measured shape from the service's draw_px (image px): the path, the area's polygon, the height's
// edge from its top to its foot, the box's top rectangle, its base and its height edges. Returns the
// image point the value's label hangs from.
function drawMeasured(c, res, s) {
  const ok = (p) => Array.isArray(p) && p.length === 2 && p.every((v) => v !== null && isFinite(v));
  const raw = res.draw_px || [];
  const at = (p) => (ok(p) ? [p[0] + 0.5, p[1] + 0.5] : null); // null: a point the service could not place
  const color = verdictColor(res.quality);
  if (res.kind === "box" && raw.length === 8) {
    const top = raw.slice(0, 4).map(at), base = raw.slice(4, 8).map(at);
    const edges = top.map((t, i) => [t, base[i]]).filter(([t, b]) => t && b);
    if (base.every(Boolean)) strokePath(c, base, s, BASE_COLOR, 1.6, true, [6, 5]);
    for (const e of edges) strokePath(c, e, s, BASE_COLOR, 1.6, false, [6, 5]);
    // the height edge: from the top corner lowest in the image, the one nearest the camera's view
    if (edges.length) strokePath(c, edges.reduce((a, b) => (b[0][1] > a[0][1] ? b : a)), s, color, 2.6, false);
    if (top.every(Boolean)) {
      fillPolygon(c, top, "rgba(255,201,77,.16)");
      strokePath(c, top, s, color, 2.6, true);
    }
  } else {
    const pts = raw.map(at).filter(Boolean);
    if (res.kind === "path") strokePath(c, pts, s, color, 2.6, false);
    else if (res.kind === "area") {
      fillPolygon(c, pts, "rgba(255,201,77,.18)");
      strokePath(c, pts, s, color, 2.6, true);
    } else if (res.kind === "height" && pts.length >= 2) {
      strokePath(c, pts.slice(0, 2), s, color, 2.6, false);
      strokePath(c, [[pts[1][0] - 12 * s, pts[1][1]], [pts[1][0] + 12 * s, pts[1][1]]], s, BASE_COLOR, 2.2, false); // the foot
    }
  }
  const drawn = raw.filter(ok);
  if (c === ctx) canvas.dataset.drawn = JSON.stringify(raw); // what the frame on screen shows
  if (!drawn.length) return null;
  const xs = drawn.map((p) => p[0] + 0.5), ys = drawn.map((p) => p[1] + 0.5);
  return [(Math.min(...xs) + Math.max(...xs)) / 2, Math.min(...ys)];
}

// app.js's draw() for a shape tool: the shape, measured unless its points are being moved or were
// moved since. Returns the image point the value's label hangs from (drawn over the handles), or null.
function drawShape(c, pts, s, moving) {
  const res = state.result;
  canvas.dataset.drawn = "[]";
  if (res && isShape(res) && !moving && !state.dirty) return drawMeasured(c, res, s);
  drawCollecting(c, pts, s);
  return null;
}

function drawShapeLabel(c, anchor, s) {
  const res = state.result;
  if (anchor && res) drawLabel(c, [anchor, anchor], s, shapeValueText(res), verdictColor(res.quality));
}

// The measured shape on the annotated PNG (app.js annotatedCanvas), with the value and interval.
function annotateShape(c, res, s) {
  const anchor = drawMeasured(c, res, s);
  (res.points || []).forEach(([x, y]) => drawHandle(c, x + 0.5, y + 0.5, s, false));
  if (!anchor) return;
  const sub = res.kind === "box"
    ? (res.dimension_intervals_m || []).map((iv, i) => `${DIMENSIONS[i][0]} ${fmtShapeInterval(res.dimensions_m[i], iv, null, "m").text}`).join(" · ")
    : fmtShapeInterval(res.value, res.interval, res.uncertainty, res.unit).text;
  drawLabel(c, [anchor, anchor], s, shapeValueText(res), verdictColor(res.quality), [sub, res.quality].filter(Boolean).join(" · "));
}

// ---- controls -------------------------------------------------------------------------------------
// Tool keys (l p a h b), Backspace (undo the last point) and Enter away from the image (end a path
// or area); the image's own keys are app.js's canvasKey.
function toolKey(e) {
  const kind = Object.keys(TOOLS).find((k) => TOOLS[k].key === e.key);
  if (kind) { setTool(kind); return true; }
  if (e.key === "Backspace") { undoPoint(); return true; }
  if (e.key === "Enter" && isShapeTool() && e.target.tagName !== "BUTTON" && enoughPoints() && (state.dirty || !state.result)) {
    measureShape(state.result ? state.result.id : null);
    return true;
  }
  return false;
}

// Called by app.js once its state exists (this file loads first, so app.js never finds it missing).
function initTools() {
  for (const b of document.querySelectorAll("#tools [data-tool]")) b.addEventListener("click", () => setTool(b.dataset.tool));
  $("undo-point").addEventListener("click", undoPoint);
  $("shape-measure").addEventListener("click", () => measureShape(state.result ? state.result.id : null));
  applyTool("distance");
}
