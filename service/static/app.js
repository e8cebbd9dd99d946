// depthruler web page: live view, freeze, place two points, measure, history. Plain JS, no build.
//
// The one rule: the frame on screen is the frame the server holds frozen and measures. Every
// change of what should be on screen (freeze, go live, reopen) bumps `state.gen`; an image that
// finishes loading for an older generation is dropped, so a live image still loading when the
// person freezes can never replace the frozen one. The page says "frozen" only once the server
// has acknowledged the freeze, and measures only a frame in that state.
"use strict";

const UNITS = { m: [1, 3], cm: [100, 1], mm: [1000, 0], in: [1 / 0.0254, 2] }; // factor, decimals
// The method names, their default and the limits come from GET /api/options (measure/options.py).
const OPTIONS = { methods: [], clickMax: 0, framesMax: 1 };
const GRAB_PX = { mouse: 16, pen: 20, touch: 30 }; // screen pixels within which a press grabs an end point
// One-sigma error (screen pixels) of a point placed with each pointer, sent as MeasureOptions.click_px in
// image pixels: the uncertainty's click term follows the hand, not one fixed guess.
const CLICK_SIGMA_PX = { mouse: 1.5, pen: 1.5, touch: 3 };
const LONG_POLL_S = 5;
const LOUPE_ZOOM = 4; // loupe pixels per screen pixel of the view
const UNDO_MS = 6000;
const WEAK_COLOR = "#ff8c1a"; // the weak stretch of a segment (style.css .weak-key)
const VIEWS = { color: "color.jpg", disparity: "disparity.png", confidence: "confidence.png" };
const NO_CONFIDENCE = "This source gives no confidence map (SGBM sources, DepthAI with align=left and the simulator do)";
const MAX_ZOOM = 8; // image magnification on screen; at 8x a phone shows a 48 px wide patch of a 640 px image

const $ = (id) => document.getElementById(id);
const canvas = $("canvas");
const ctx = canvas.getContext("2d");
const loupe = $("loupe");
const lctx = loupe.getContext("2d");

const state = {
  token: new URLSearchParams(location.search).get("token") || sessionStorage.getItem("depthruler-token") || "",
  frame: null,        // frame JSON of the image on screen
  img: null,          // its decoded image
  mode: "live",       // "live" | "freezing" | "frozen"
  gen: 0,             // bumped whenever what must be on screen changes
  freezing: null,     // the pending freeze (a promise of true/false)
  looping: false,     // the live long-poll loop runs
  view: "color",
  tool: "distance",   // the measuring tool (tools.js TOOLS): distance, path, area, height, box
  points: [],         // [[x, y], ...] in image pixels
  result: null,       // the measurement on screen
  seq: 0,             // measurement requests issued; only the newest one's answer is shown
  press: null,        // {pointerId, index, offset, type, moved} while a point is placed or dragged
  pointerTypes: [],   // the pointer type that last placed or moved each end point
  units: localStorage.getItem("depthruler-units") || "m",
  method: localStorage.getItem("depthruler-method") || "", // "" until the API says the default
  recording: false,
  source: null,       // the last /api/source answer
  scale: null,        // the depth scale of the frame on screen (disparity view colour bar)
  history: [],
  filter: "",
  pendingDelete: null, // {record, timer} of a deletion that can still be undone
  depthQuery: { busy: false, next: null },
  hoverDepth: null,   // the last depth readout (GET /api/frames/{id}/depth)
  scaleAt: 0,         // when the colour bar's scale was last fetched (performance.now())
  zoom: { k: 1, x: 0, y: 0 }, // magnification and the image point at the view's top-left (zoom and pan)
  touches: new Map(), // pointerId -> [clientX, clientY] of the fingers on the image
  gesture: null,      // a two-finger pinch / pan under way
  pan: null,          // a space-drag pan under way
  space: { down: false, used: false }, // space held (pans with the mouse); used: a drag happened meanwhile
  readMode: false,    // touch "read depth": a press reads the depth under it and stores nothing
  active: 0,          // the handle the keyboard moves
  dirty: false,       // the points moved since the last measurement (keyboard nudges wait for Enter)
  nudging: false,     // the keyboard is moving a handle (the loupe shows it)
  saved: null,        // the history record reopened on screen (until the points change or the view goes live)
};

// ---- HTTP ---------------------------------------------------------------------------------------
function withToken(url) {
  if (!state.token) return url;
  return url + (url.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(state.token);
}

async function api(path, options = {}) {
  const headers = Object.assign({}, options.headers || {});
  if (state.token) headers.Authorization = "Bearer " + state.token;
  const method = (options.method || "GET").toUpperCase();
  let body = options.body;
  if (method !== "GET" && method !== "DELETE") {
    // every state-changing request is JSON, with an empty object when there is nothing to say
    headers["Content-Type"] = "application/json";
    body = typeof body === "string" ? body : JSON.stringify(body || {});
  }
  const res = await fetch(path, Object.assign({}, options, { method, headers, body }));
  if (res.status === 401) {
    const t = prompt("This depthruler needs its access token:");
    if (t) {
      state.token = t.trim();
      sessionStorage.setItem("depthruler-token", state.token);
      return api(path, options);
    }
  }
  const isJson = (res.headers.get("content-type") || "").includes("json");
  const data = isJson ? await res.json() : await res.text();
  if (!res.ok) {
    const err = new Error(typeof data === "object" && data.detail ? data.detail : `${res.status} ${res.statusText}`);
    err.status = res.status;
    throw err;
  }
  return data;
}

function loadImage(url) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => reject(new Error("image failed to load: " + url));
    img.src = withToken(url);
  });
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// ---- formatting ---------------------------------------------------------------------------------
function fmt(metres, withUnit = true) {
  if (metres === null || metres === undefined || !isFinite(metres)) return "—";
  const [k, dec] = UNITS[state.units];
  return (metres * k).toFixed(dec) + (withUnit ? " " + state.units : "");
}

// A small length (an uncertainty) in the unit that reads best: mm or cm under a metre when the
// page is in metres, else the page's unit; one significant digit, two when it starts with a 1.
function fmtSmall(metres) {
  let unit = state.units;
  if (unit === "m") unit = metres < 0.01 ? "mm" : metres < 1 ? "cm" : "m";
  const v = metres * UNITS[unit][0];
  if (!(v > 0)) return "0 " + unit;
  const mag = Math.floor(Math.log10(v));
  const lead = v / 10 ** mag;
  const digits = Math.max(0, -(mag - (lead < 2 ? 1 : 0)));
  return v.toFixed(Math.min(6, digits)) + " " + unit;
}

// The measurement's 95 % interval: the service's interval_m when it gives one, else ±1.96σ.
function interval95(res) {
  const iv = res.interval_m;
  if (Array.isArray(iv) && iv.length === 2 && iv.every((v) => v !== null && isFinite(v))) return { lo: iv[0], hi: iv[1], from: "interval" };
  if (res.uncertainty_m !== null && res.uncertainty_m !== undefined && isFinite(res.uncertainty_m) && res.distance_m !== null) {
    const h = 1.96 * res.uncertainty_m;
    return { lo: res.distance_m - h, hi: res.distance_m + h, from: "sigma" };
  }
  return null;
}

function fmtInterval(res) {
  const iv = interval95(res);
  if (!iv) return "uncertainty unknown";
  const half = (iv.hi - iv.lo) / 2;
  const mid = (iv.hi + iv.lo) / 2;
  const d = res.distance_m;
  // symmetric enough to read as ±: the centre within a tenth of the half-width of the value
  if (d !== null && Math.abs(mid - d) <= 0.1 * half + 1e-12) return `${fmt(d)} ± ${fmtSmall(half)}`;
  return `${fmt(d)} (${fmt(iv.lo, false)} – ${fmt(iv.hi)})`;
}

function fmtPoint3(p) {
  if (!p || p.some((v) => v === null || !isFinite(v))) return "—";
  return `(${p.map((v) => fmt(v, false)).join(", ")}) ${state.units}`;
}

// ---- frames: the live loop, freezing ------------------------------------------------------------
function imageUrl(frame) {
  // JPEG q85 for the colour view: ~20x smaller and ~30x cheaper to encode than PNG (exports use color.png)
  return `api/frames/${frame.id}/${VIEWS[state.view]}`;
}

// Put `frame` on screen unless what must be on screen changed (gen) while its image loaded.
async function showFrame(frame, gen) {
  showViews(frame);
  if (state.view === "confidence" && !frame.has_confidence) applyView("color"); // the source changed under it
  const url = imageUrl(frame);
  const img = await loadImage(url);
  if (gen !== state.gen) return false;
  if (canvas.width !== img.naturalWidth || canvas.height !== img.naturalHeight) {
    canvas.width = img.naturalWidth;
    canvas.height = img.naturalHeight;
    resetZoom();
    fitCanvas();
  }
  state.frame = frame;
  state.img = img;
  canvas.dataset.frameId = String(frame.id);
  canvas.dataset.image = url; // which of the frame's images is on screen
  updateTag();
  showReplayPosition();
  // the colour bar's scale: for every frozen frame, at most once a second while live
  if (state.view === "disparity" && (state.mode !== "live" || !(state.scaleAt > performance.now() - 1000))) {
    state.scaleAt = performance.now();
    loadScale(frame);
  }
  draw();
  return true;
}

// Follow the stream: long-poll for a frame newer than the one shown, show it, repeat. One request
// at a time, so the view runs at the source's rate (or as fast as images load, if slower).
async function liveLoop() {
  if (state.looping) return;
  state.looping = true;
  try {
    while (state.mode === "live") {
      if (document.hidden) { await sleep(400); continue; }
      const gen = state.gen;
      let frame;
      try {
        frame = await api(`api/frames/latest?after=${state.frame ? state.frame.id : 0}&wait=${LONG_POLL_S}`);
      } catch (e) {
        await sleep(1000); // no frame yet: the status pill says why
        continue;
      }
      if (gen !== state.gen || state.mode !== "live") continue;
      if (state.frame && frame.id === state.frame.id) continue; // nothing newer within the wait
      try { await showFrame(frame, gen); } catch (e) { await sleep(200); }
    }
  } finally {
    state.looping = false;
  }
}

// Freeze the frame on screen. Resolves true once the server holds it frozen.
function freeze() {
  if (state.mode === "frozen") return Promise.resolve(true);
  if (state.mode === "freezing") return state.freezing;
  if (!state.frame) return Promise.resolve(false);
  const shown = state.frame;
  state.mode = "freezing";
  const gen = ++state.gen; // from here no live image may replace the one on screen
  updateFreezeButton();
  updateTag();
  state.freezing = api(`api/frames/${shown.id}/freeze`, { method: "POST" }).then(
    (f) => {
      if (gen !== state.gen) { // the person went live again meanwhile: let the frame go
        api(`api/frames/${f.id}/freeze`, { method: "DELETE" }).catch(() => {});
        return false;
      }
      state.frame = f;
      state.mode = "frozen";
      updateFreezeButton();
      updateTag();
      // A view switched just before the freeze had its image load dropped by the new gen: show the
      // frozen frame in the view the buttons say.
      if (canvas.dataset.image !== imageUrl(f)) showFrame(f, gen).catch((e) => showError(e.message));
      else if (state.view === "disparity") loadScale(f);
      return true;
    },
    (e) => {
      if (gen === state.gen) {
        state.mode = "live";
        state.gen++;
        state.points = [];
        updateFreezeButton();
        updateTag();
        showError(`Could not freeze frame ${shown.id}: ${e.message}`);
        draw();
        liveLoop();
      }
      return false;
    },
  );
  return state.freezing;
}

function goLive() {
  if (state.mode === "live") return;
  const held = state.mode === "frozen" ? state.frame : null;
  state.mode = "live";
  state.gen++;
  if (held) api(`api/frames/${held.id}/freeze`, { method: "DELETE" }).catch(() => {});
  resetZoom(); // zoom and pan belong to the frozen frame
  clearPoints();
  updateFreezeButton();
  updateTag();
  liveLoop();
}

function updateFreezeButton() {
  const b = $("freeze");
  b.textContent = state.mode === "live" ? "Freeze" : "Go live";
  b.classList.toggle("frozen", state.mode !== "live");
}

// "frame k of n" (1-based) of a frame from a recording; n from the source's status ("frame k" when unknown).
function framePosition(index, frames) {
  if (index === null || index === undefined) return "";
  return frames > 0 ? `frame ${index + 1} of ${frames}` : `frame ${index + 1}`;
}

function updateTag() {
  const f = state.frame;
  const tag = $("frame-tag");
  canvas.dataset.frozen = state.mode === "frozen" ? "1" : "";
  if (!f) { tag.textContent = ""; return; }
  const saved = state.saved && state.mode === "frozen" ? state.saved : null;
  const word = saved ? `saved #${saved.id}` : state.mode === "frozen" ? "frozen" : state.mode === "freezing" ? "freezing…" : "live";
  const r = state.source && state.source.replay;
  const index = saved && saved.frame_index !== undefined ? saved.frame_index : f.replay_index;
  const pos = framePosition(index, r ? r.frames : 0);
  const where = saved && saved.recording ? ` · ${saved.recording}` : "";
  tag.textContent = `${word}${where}${pos ? " · " + pos : ""} · id ${f.id} · ${f.width}×${f.height}`;
  tag.dataset.index = index === null || index === undefined ? "" : String(index);
}

// The confidence view is offered only for a frame that carries a confidence map.
function showViews(frame) {
  const b = $("view-confidence");
  b.disabled = !frame.has_confidence;
  b.title = frame.has_confidence ? "Matcher confidence: black = no support, white = fully supported (c)" : NO_CONFIDENCE;
}

function applyView(view) {
  state.view = view;
  for (const v of Object.keys(VIEWS)) $(`view-${v}`).classList.toggle("active", view === v);
  $("colorbar").classList.toggle("hidden", view !== "disparity");
  $("confidence-bar").classList.toggle("hidden", view !== "confidence");
  canvas.dataset.view = view;
}

async function setView(view) {
  if (view === "confidence" && !(state.frame && state.frame.has_confidence)) return;
  applyView(view);
  if (state.frame) {
    try { await showFrame(state.frame, state.gen); } catch (e) { showError(e.message); }
  }
}

// ---- depth: the readout under the pointer, the colour bar ---------------------------------------
// One request in flight; a newer position replaces a waiting one.
// `read`: a read-depth press, whose answer is shown even when the live view has moved on meanwhile.
function queryDepth(p, read = false) {
  if (!state.frame) return;
  const q = state.depthQuery;
  q.next = { frame: state.frame, x: Math.round(p[0]), y: Math.round(p[1]), read };
  if (q.busy) return;
  q.busy = true;
  (async () => {
    while (q.next) {
      const job = q.next;
      q.next = null;
      try {
        const r = await api(`api/frames/${job.frame.id}/depth?x=${job.x}&y=${job.y}`);
        if (state.frame && (job.read || job.frame.id === state.frame.id)) showDepth(r);
      } catch (e) { /* a live frame may have left the ring; the next position asks again */ }
    }
    q.busy = false;
  })();
}

function showDepth(r) {
  const el = $("readout");
  el.dataset.depthM = r.depth_m === null ? "" : String(r.depth_m);
  el.dataset.px = `${r.x},${r.y}`;
  el.dataset.frameId = String(r.frame_id);
  el.textContent = `depth ${r.depth_m === null ? "no data" : fmt(r.depth_m)} · px (${r.x}, ${r.y})`;
  state.hoverDepth = r;
  drawLoupe();
}

async function loadScale(frame) {
  try {
    const s = await api(`api/frames/${frame.id}/depth-scale`);
    if (!state.frame || state.frame.id !== frame.id) return;
    state.scale = s;
    drawColorbar();
  } catch (e) { /* a live frame may have left the ring; the next one brings its scale */ }
}

// The colour bar of the depth view, labelled in depth (the colours run linearly in disparity, so
// equal steps in metres are not equally spaced).
function drawColorbar() {
  const s = state.scale;
  const bar = $("colorbar");
  if (!s || !s.disparity_px) { bar.classList.add("hidden"); return; }
  bar.classList.toggle("hidden", state.view !== "disparity");
  const [lo, hi] = s.disparity_px;
  const [near, far] = s.depth_m;
  $("colorbar-ramp").style.background = `linear-gradient(to right, ${s.colors.join(", ")})`;
  const ticks = $("colorbar-ticks");
  const pos = (z) => ((s.fx_baseline / z - s.doffs - lo) / Math.max(hi - lo, 1e-9)) * 100; // far left, near right
  const labels = depthTicks(s).map((z) => {
    const x = pos(z);
    const el = Object.assign(document.createElement("span"), { textContent: fmtTick(z), style: `left:${x.toFixed(2)}%` });
    el.dataset.m = String(z);
    el.dataset.x = String(x);
    return el;
  });
  ticks.replaceChildren(...labels);
  bar.dataset.near = String(near);
  bar.dataset.far = String(far);
  bar.title = `colours span ${fmt(far)} (left) to ${fmt(near)} (right); black: no depth`;
  $("colorbar-range").textContent = `${fmt(near)} – ${fmt(far)}`;
}

// 4 to 6 round depths for the colour bar, spread evenly along it. The colours run linearly in
// disparity, so evenly spaced depths would crowd at the far end: the ticks are taken at even steps of
// the bar and each rounded (in the page's unit) to the nearest 1, 1.5, 2, 2.5, 3, 4, 5, 6 or 8 times a
// power of ten; a rounding that lands two ticks on one value, or off the bar, drops one.
const ROUND_STEPS = [1, 1.5, 2, 2.5, 3, 4, 5, 6, 8, 10];

function roundNice(v) {
  const mag = 10 ** Math.floor(Math.log10(v));
  const m = v / mag;
  const best = ROUND_STEPS.reduce((a, b) => (Math.abs(b - m) < Math.abs(a - m) ? b : a));
  return +(best * mag).toPrecision(3);
}

function depthTicks(s) {
  const [lo, hi] = s.disparity_px;
  const k = UNITS[state.units][0];
  if (!(hi > lo) || !(s.fx_baseline > 0)) return [];
  const depthAt = (x) => s.fx_baseline / (lo + x * (hi - lo) + s.doffs); // bar position 0..1 -> metres
  const inside = (z) => { const d = s.fx_baseline / z - s.doffs; return d >= lo - 1e-9 && d <= hi + 1e-9; };
  for (const n of [5, 6, 7, 8]) { // more candidates when rounding merges some
    const out = [];
    for (let i = 0; i < n; i++) {
      const z = depthAt(0.04 + (0.92 * i) / (n - 1));
      if (!(z > 0 && isFinite(z))) continue;
      const r = roundNice(z * k) / k;
      if (inside(r) && !out.includes(r)) out.push(r);
    }
    if (out.length >= 4) return out.slice(0, 6);
  }
  return [depthAt(0.04), depthAt(0.5), depthAt(0.96)].filter((z) => z > 0 && isFinite(z)); // a very narrow span
}

// A tick's label: the round value as it is ("2.5 m", "400 mm"), without the trailing zeros of fmt().
function fmtTick(metres) {
  const v = metres * UNITS[state.units][0];
  return `${+v.toPrecision(3)} ${state.units}`;
}

// ---- drawing ------------------------------------------------------------------------------------
function fitCanvas() {
  // The largest size with the image's aspect ratio that fits the stage's width and the window's height.
  const stage = $("stage");
  const maxW = stage.clientWidth;
  const phone = window.innerWidth < 700;
  const maxH = Math.max(160, window.innerHeight * (phone ? 0.42 : 1) - (phone ? 0 : stage.getBoundingClientRect().top + 60));
  const k = Math.min(maxW / canvas.width, maxH / canvas.height);
  canvas.style.width = `${Math.floor(canvas.width * k)}px`;
  canvas.style.height = `${Math.floor(canvas.height * k)}px`;
}

function clickPx() {
  // the least precise of the points' pointers, in image pixels at the displayed scale (and zoom)
  const sigma = Math.max(CLICK_SIGMA_PX.mouse, ...state.points.map((_, i) => CLICK_SIGMA_PX[state.pointerTypes[i]] || CLICK_SIGMA_PX.mouse));
  return Math.min(OPTIONS.clickMax, Math.round(sigma * screenScale() * 100) / 100);
}

// ---- zoom and pan -------------------------------------------------------------------------------
// The canvas holds the image at its own resolution; zoom draws the part of the image from (x, y) (image
// coordinates, pixel i spans [i, i + 1]) magnified k times. Every conversion between the screen and the
// image goes through clientToImage / imageToClient, so handles, clicks and the loupe agree at any zoom.
function canvasPerCss() {
  const r = canvas.getBoundingClientRect();
  return r.width > 0 ? canvas.width / r.width : 1;
}

function screenScale() { // image pixels per CSS pixel
  return canvasPerCss() / state.zoom.k;
}

function clientToImage(cx, cy) {
  const r = canvas.getBoundingClientRect(), z = state.zoom;
  return [z.x + ((cx - r.left) * (canvas.width / r.width)) / z.k - 0.5, z.y + ((cy - r.top) * (canvas.height / r.height)) / z.k - 0.5];
}

function imageToClient([x, y]) {
  const r = canvas.getBoundingClientRect(), z = state.zoom;
  return [r.left + ((x + 0.5 - z.x) * z.k * r.width) / canvas.width, r.top + ((y + 0.5 - z.y) * z.k * r.height) / canvas.height];
}

function clampPan() {
  const z = state.zoom;
  z.x = Math.min(Math.max(z.x, 0), canvas.width - canvas.width / z.k);
  z.y = Math.min(Math.max(z.y, 0), canvas.height - canvas.height / z.k);
}

// Zoom to k keeping the image point under client position (cx, cy) where it is on screen.
function zoomAt(k, cx, cy) {
  const z = state.zoom;
  const [u, v] = clientToImage(cx, cy).map((c) => c + 0.5);
  const r = canvas.getBoundingClientRect();
  const ox = (cx - r.left) * (canvas.width / r.width), oy = (cy - r.top) * (canvas.height / r.height);
  z.k = Math.min(Math.max(k, 1), MAX_ZOOM);
  z.x = u - ox / z.k;
  z.y = v - oy / z.k;
  clampPan();
  showZoom();
  draw();
}

function resetZoom() {
  Object.assign(state.zoom, { k: 1, x: 0, y: 0 });
  showZoom();
}

// Pan so that image point p is inside the view (a handle nudged by the keyboard stays visible).
function keepVisible(p) {
  const z = state.zoom, w = canvas.width / z.k, h = canvas.height / z.k, m = 0.1;
  if (p[0] + 0.5 < z.x + m * w) z.x = p[0] + 0.5 - m * w;
  if (p[0] + 0.5 > z.x + (1 - m) * w) z.x = p[0] + 0.5 - (1 - m) * w;
  if (p[1] + 0.5 < z.y + m * h) z.y = p[1] + 0.5 - m * h;
  if (p[1] + 0.5 > z.y + (1 - m) * h) z.y = p[1] + 0.5 - (1 - m) * h;
  clampPan();
  showZoom();
}

function showZoom() {
  const z = state.zoom;
  canvas.dataset.zoom = String(z.k);
  canvas.dataset.viewX = String(z.x);
  canvas.dataset.viewY = String(z.y);
  $("zoom-reset").classList.toggle("hidden", z.k === 1);
  $("zoom-reset").textContent = `${z.k.toFixed(1)}× ⟲`;
}

function drawSegment(c, pts, s) {
  c.lineCap = "round";
  c.strokeStyle = "rgba(0,0,0,.65)";
  c.lineWidth = 5 * s;
  c.beginPath(); c.moveTo(...pts[0]); c.lineTo(...pts[1]); c.stroke();
  c.strokeStyle = "#ffc94d";
  c.lineWidth = 2.2 * s;
  c.beginPath(); c.moveTo(...pts[0]); c.lineTo(...pts[1]); c.stroke();
}

// The stretches of the segment where the matcher's support is weak (the measurement's weak_stretches,
// [t0, t1] fractions from the first point to the second): a dashed orange band under the samples,
// wider than their dots, so the inlier colours stay readable on it.
function drawWeak(c, pts, s, stretches) {
  const [[x1, y1], [x2, y2]] = pts;
  c.save();
  c.lineCap = "butt";
  c.strokeStyle = WEAK_COLOR;
  c.lineWidth = 12 * s;
  c.setLineDash([8 * s, 5 * s]);
  for (const [t0, t1] of stretches) {
    c.beginPath();
    c.moveTo(x1 + t0 * (x2 - x1), y1 + t0 * (y2 - y1));
    c.lineTo(x1 + t1 * (x2 - x1), y1 + t1 * (y2 - y1));
    c.stroke();
  }
  c.restore();
}

// An end point drawn as a ring and four ticks that stop short of the point: the clicked pixel
// itself stays visible, however large the handle is on a phone.
function drawHandle(c, x, y, s, active) {
  const r = 10 * s, gap = 3.5 * s, out = 15 * s;
  c.lineWidth = 3.2 * s;
  c.strokeStyle = "rgba(0,0,0,.75)";
  ring(); ticks();
  c.lineWidth = 1.6 * s;
  c.strokeStyle = active ? "#7fd1ff" : "#ffc94d";
  ring(); ticks();
  function ring() { c.beginPath(); c.arc(x, y, r, 0, 2 * Math.PI); c.stroke(); }
  function ticks() {
    c.beginPath();
    for (const [dx, dy] of [[1, 0], [-1, 0], [0, 1], [0, -1]]) { c.moveTo(x + dx * gap, y + dy * gap); c.lineTo(x + dx * out, y + dy * out); }
    c.stroke();
  }
}

// The handle being moved: by a press, else the keyboard's active one while the canvas has focus.
function activeHandle() {
  if (state.press && !state.press.read) return state.press.index;
  return document.activeElement === canvas && state.points.length ? Math.min(state.active, state.points.length - 1) : -1;
}

function draw() {
  const z = state.zoom;
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.setTransform(z.k, 0, 0, z.k, -z.x * z.k, -z.y * z.k); // from here on: image coordinates
  ctx.imageSmoothingEnabled = z.k < 2; // zoomed in: whole image pixels, to place a point on one
  if (state.img) ctx.drawImage(state.img, 0, 0);
  const s = screenScale();
  const pts = state.points.map(([x, y]) => [x + 0.5, y + 0.5]);
  const moving = state.press && !state.press.read;
  const active = activeHandle();
  if (isShapeTool()) {
    canvas.dataset.weak = "[]";
    const anchor = drawShape(ctx, pts, s, moving); // tools.js
    pts.forEach(([x, y], i) => drawHandle(ctx, x, y, s, active === i));
    drawShapeLabel(ctx, anchor, s);
  } else drawDistance(pts, s, moving, active);
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  canvas.dataset.points = JSON.stringify(state.points);
  canvas.dataset.active = String(active);
  drawLoupe();
}

// The distance tool's drawing: the segment, its weak stretches, the samples, the handles, the value.
function drawDistance(pts, s, moving, active) {
  const res = state.result;
  canvas.dataset.drawn = "[]";
  if (pts.length === 2) drawSegment(ctx, pts, s);
  const weak = res && pts.length === 2 && !moving && !state.dirty && Array.isArray(res.weak_stretches) ? res.weak_stretches : [];
  if (weak.length) drawWeak(ctx, pts, s, weak);
  canvas.dataset.weak = JSON.stringify(weak);
  if (res && res.samples_px && state.points.length === 2 && !moving && !state.dirty) {
    ctx.lineWidth = 0.8 * s;
    ctx.strokeStyle = "rgba(0,0,0,.7)";
    for (let i = 0; i < res.samples_px.length; i++) {
      const [x, y] = res.samples_px[i];
      ctx.fillStyle = res.support[i] ? "#3ddc84" : "#ff5c5c";
      ctx.beginPath();
      ctx.arc(x + 0.5, y + 0.5, 2.6 * s, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
    }
  }
  pts.forEach(([x, y], i) => drawHandle(ctx, x, y, s, active === i));
  if (res && pts.length === 2 && !moving && !state.dirty) drawLabel(ctx, pts, s, fmt(res.distance_m), verdictColor(res.quality));
}

function verdictColor(q) {
  return q === "good" ? "#3ddc84" : q === "check" ? "#ffb347" : q === "unreliable" ? "#ff5c5c" : "#ffc94d";
}

function drawLabel(c, pts, s, label, color, sub) {
  let mx = (pts[0][0] + pts[1][0]) / 2;
  const my = (pts[0][1] + pts[1][1]) / 2;
  c.font = `600 ${Math.round(16 * s)}px system-ui, sans-serif`;
  let w = c.measureText(label).width;
  let subFont = `${Math.round(12 * s)}px system-ui, sans-serif`;
  if (sub) { c.font = subFont; w = Math.max(w, c.measureText(sub).width); }
  w += 16 * s;
  // inside the part of the image in view (a shape near the border keeps its label readable)
  const [x0, x1] = c === ctx ? [state.zoom.x, state.zoom.x + canvas.width / state.zoom.k] : [0, c.canvas.width];
  mx = Math.min(Math.max(mx, x0 + w / 2 + 2 * s), x1 - w / 2 - 2 * s);
  const h = (sub ? 42 : 26) * s;
  const top = Math.max(2 * s, my - h - 10 * s);
  c.fillStyle = "rgba(15,18,22,.85)";
  c.beginPath(); c.roundRect(mx - w / 2, top, w, h, 6 * s); c.fill();
  c.textAlign = "center"; c.textBaseline = "middle";
  c.fillStyle = color;
  c.font = `600 ${Math.round(16 * s)}px system-ui, sans-serif`;
  c.fillText(label, mx, top + 13 * s);
  if (sub) { c.font = subFont; c.fillStyle = "#cfd6df"; c.fillText(sub, mx, top + 31 * s); }
}

// The point the loupe magnifies: the one being placed or dragged, the one read in read-depth mode,
// or the handle the keyboard nudges.
function loupeTarget() {
  const press = state.press;
  if (press) return { p: press.read ? press.at : state.points[press.index], touchy: press.type !== "mouse" };
  if (state.nudging && state.points[state.active]) return { p: state.points[state.active], touchy: false };
  return null;
}

// The loupe: a magnified view of the image around the point being placed or dragged, drawn away
// from the finger (above it, or below when there is no room) with a crosshair on the exact pixel.
function drawLoupe() {
  const target = loupeTarget();
  if (!target || !target.p || !state.img) { loupe.classList.add("hidden"); return; }
  const { p, touchy } = target;
  const dpr = window.devicePixelRatio || 1;
  const size = 132;
  if (loupe.width !== Math.round(size * dpr)) { loupe.width = loupe.height = Math.round(size * dpr); }
  loupe.style.width = loupe.style.height = `${size}px`;
  const srcSize = (size / LOUPE_ZOOM) * screenScale(); // image pixels across the loupe: LOUPE_ZOOM x the view
  lctx.imageSmoothingEnabled = false;
  lctx.fillStyle = "#000";
  lctx.fillRect(0, 0, loupe.width, loupe.height);
  lctx.drawImage(state.img, p[0] + 0.5 - srcSize / 2, p[1] + 0.5 - srcSize / 2, srcSize, srcSize, 0, 0, loupe.width, loupe.height);
  const c = loupe.width / 2, k = loupe.width / srcSize; // loupe pixels per image pixel
  lctx.strokeStyle = "rgba(0,0,0,.8)"; lctx.lineWidth = 3 * dpr;
  cross(); lctx.strokeStyle = "#ffc94d"; lctx.lineWidth = 1.2 * dpr; cross();
  lctx.strokeRect(c - k / 2, c - k / 2, k, k); // the pixel itself
  const d = state.hoverDepth;
  if (d && d.x === Math.round(p[0]) && d.y === Math.round(p[1])) {
    const text = d.depth_m === null ? "no depth" : fmt(d.depth_m);
    lctx.font = `600 ${12 * dpr}px system-ui, sans-serif`;
    lctx.textAlign = "center"; lctx.textBaseline = "bottom";
    lctx.fillStyle = "rgba(0,0,0,.7)"; lctx.fillRect(0, loupe.height - 18 * dpr, loupe.width, 18 * dpr);
    lctx.fillStyle = "#fff"; lctx.fillText(text, c, loupe.height - 3 * dpr);
  }
  function cross() {
    lctx.beginPath();
    for (const [dx, dy] of [[1, 0], [-1, 0], [0, 1], [0, -1]]) { lctx.moveTo(c + dx * 6 * dpr, c + dy * 6 * dpr); lctx.lineTo(c + dx * 26 * dpr, c + dy * 26 * dpr); }
    lctx.stroke();
  }
  // position (viewport coordinates; it may cover the toolbar): above the point for touch, where the
  // finger is not, beside it for a mouse; below or to the side when there is no room
  const [sx, sy] = imageToClient(p);
  const vw = document.documentElement.clientWidth, vh = window.innerHeight;
  let lx = touchy ? sx - size / 2 : sx + 30;
  let ly = touchy ? sy - size - 56 : sy - size - 30;
  if (ly < 4) ly = touchy ? sy + 70 : sy + 30;
  if (lx + size > vw - 4) lx = touchy ? vw - size - 4 : sx - size - 30;
  loupe.style.left = `${Math.max(4, lx)}px`;
  loupe.style.top = `${Math.max(4, Math.min(ly, vh - size - 4))}px`;
  loupe.classList.remove("hidden");
  loupe.dataset.x = String(Math.round(p[0]));
  loupe.dataset.y = String(Math.round(p[1]));
}

// ---- pointer input (mouse, pen and touch) -------------------------------------------------------
// One pointer places or drags a point (or, in read-depth mode, reads the depth under it); a second
// finger turns the press into a pinch (zoom) and two-finger drag (pan); a mouse pans with space held.
function toImage(ev) {
  return clientToImage(ev.clientX, ev.clientY);
}

function clampToImage([x, y]) {
  return [Math.min(Math.max(x, 0), canvas.width - 1), Math.min(Math.max(y, 0), canvas.height - 1)];
}

function handleAt(p, type) {
  const limit = (GRAB_PX[type] || GRAB_PX.mouse) * screenScale();
  let best = -1, bestD = limit;
  state.points.forEach(([x, y], i) => {
    const d = Math.hypot(x - p[0], y - p[1]);
    if (d <= bestD) { best = i; bestD = d; }
  });
  return best;
}

function setReadMode(on) {
  state.readMode = on;
  const b = $("read-depth");
  b.classList.toggle("active", on);
  b.setAttribute("aria-pressed", on ? "true" : "false");
  canvas.dataset.mode = on ? "read" : "measure";
  $("hint").textContent = on ? "Read depth: touch the image to read the depth there; nothing is stored." : toolSpec().hint;
}

function startGesture() {
  // the first finger's press becomes part of the gesture: a point it had just placed is taken back
  const press = state.press;
  if (press && !press.read && press.isNew) {
    state.points = press.before.points;
    state.result = press.before.result;
    showResult(state.result);
  } else if (press && !press.read && press.moved) {
    state.points[press.index] = press.before.points[press.index];
  }
  state.press = null;
  const [a, b] = [...state.touches.values()];
  state.gesture = {
    d0: Math.hypot(a[0] - b[0], a[1] - b[1]) || 1, k0: state.zoom.k,
    anchor: clientToImage((a[0] + b[0]) / 2, (a[1] + b[1]) / 2).map((c) => c + 0.5), // the image point under the fingers' middle
  };
  if (state.mode === "live") freeze();
}

function moveGesture() {
  const g = state.gesture, z = state.zoom;
  const [a, b] = [...state.touches.values()];
  const mx = (a[0] + b[0]) / 2, my = (a[1] + b[1]) / 2;
  z.k = Math.min(Math.max((g.k0 * Math.hypot(a[0] - b[0], a[1] - b[1])) / g.d0, 1), MAX_ZOOM);
  // the anchor stays under the fingers' middle: moving both fingers pans
  const r = canvas.getBoundingClientRect();
  z.x = g.anchor[0] - ((mx - r.left) * (canvas.width / r.width)) / z.k;
  z.y = g.anchor[1] - ((my - r.top) * (canvas.height / r.height)) / z.k;
  clampPan();
  showZoom();
  draw();
}

canvas.addEventListener("pointerdown", (ev) => {
  if (!state.frame || ev.button > 0) return;
  ev.preventDefault();
  canvas.focus({ preventScroll: true });
  if (ev.pointerType === "touch") {
    state.touches.set(ev.pointerId, [ev.clientX, ev.clientY]);
    canvas.setPointerCapture(ev.pointerId);
    if (state.touches.size === 2) { startGesture(); draw(); return; }
    if (state.touches.size > 2 || state.gesture) return;
  }
  if (state.press || state.pan) return;
  canvas.setPointerCapture(ev.pointerId);
  state.nudging = false;
  if (ev.pointerType === "mouse" && state.space.down) {
    state.space.used = true;
    state.pan = { pointerId: ev.pointerId, start: [ev.clientX, ev.clientY], view: [state.zoom.x, state.zoom.y] };
    if (state.mode === "live") freeze();
    canvas.style.cursor = "grabbing";
    return;
  }
  const p = toImage(ev);
  if (state.readMode) {
    state.press = { pointerId: ev.pointerId, read: true, at: clampToImage(p), type: ev.pointerType };
    queryDepth(state.press.at, true);
    draw();
    return;
  }
  const grab = canGrab() ? handleAt(p, ev.pointerType) : -1; // tools.js: which tool may grab what
  showError("");
  const before = { points: state.points.map((q) => q.slice()), result: state.result };
  if (grab >= 0) {
    // grab the handle where it is: the point keeps its offset from the finger instead of jumping under it
    const q = state.points[grab];
    state.press = { pointerId: ev.pointerId, index: grab, offset: [q[0] - p[0], q[1] - p[1]], type: ev.pointerType, moved: false, isNew: false, before };
  } else {
    if (state.mode === "live") freeze(); // the frame on screen is frozen now; the point lands on it
    if (startsAgain()) { state.points = []; state.pointerTypes = []; state.result = null; showResult(null); }
    state.points.push(clampToImage(p));
    state.press = { pointerId: ev.pointerId, index: state.points.length - 1, offset: [0, 0], type: ev.pointerType, moved: false, isNew: true, before };
  }
  state.active = state.press.index;
  state.pointerTypes[state.press.index] = ev.pointerType;
  queryDepth(state.points[state.press.index]);
  draw();
});

canvas.addEventListener("pointermove", (ev) => {
  if (state.touches.has(ev.pointerId)) {
    state.touches.set(ev.pointerId, [ev.clientX, ev.clientY]);
    if (state.gesture) { if (state.touches.size === 2) moveGesture(); return; }
  }
  if (state.pan && state.pan.pointerId === ev.pointerId) {
    const k = screenScale(), pan = state.pan;
    state.zoom.x = pan.view[0] - (ev.clientX - pan.start[0]) * k;
    state.zoom.y = pan.view[1] - (ev.clientY - pan.start[1]) * k;
    clampPan();
    showZoom();
    draw();
    return;
  }
  const p = toImage(ev);
  const press = state.press;
  if (press && press.pointerId === ev.pointerId) {
    if (press.read) { press.at = clampToImage(p); queryDepth(press.at, true); } else queryDepth(movePress(press, ev));
    draw();
  } else if (!press && ev.pointerType === "mouse") {
    const inside = p[0] >= -0.5 && p[1] >= -0.5 && p[0] <= canvas.width - 0.5 && p[1] <= canvas.height - 0.5;
    if (inside) queryDepth(clampToImage(p));
    canvas.style.cursor = state.space.down ? "grab" : canGrab() && handleAt(p, "mouse") >= 0 ? "grab" : "crosshair";
  }
});

function movePress(press, ev) {
  const p = toImage(ev);
  const q = clampToImage([p[0] + press.offset[0], p[1] + press.offset[1]]);
  const old = state.points[press.index];
  if (Math.hypot(q[0] - old[0], q[1] - old[1]) > 0) press.moved = true;
  state.points[press.index] = q;
  return q;
}

async function endPress(ev) {
  if (state.touches.delete(ev.pointerId) && state.gesture) {
    if (state.touches.size === 0) state.gesture = null; // the gesture ends when the last finger lifts
    return;
  }
  if (state.pan && state.pan.pointerId === ev.pointerId) {
    state.pan = null;
    canvas.style.cursor = state.space.down ? "grab" : "crosshair";
    return;
  }
  const press = state.press;
  if (!press || press.pointerId !== ev.pointerId) return;
  if (ev.type === "pointerup" && !press.read) movePress(press, ev); // where the finger lifted, even if its last move was coalesced
  state.press = null;
  if (canvas.hasPointerCapture(ev.pointerId)) canvas.releasePointerCapture(ev.pointerId);
  draw();
  if (press.read) return; // reading depth stores nothing
  if (!press.isNew) {
    if (press.moved) pointMoved(); // tools.js: the tool measures again
    return;
  }
  pointPlaced(); // tools.js: the tool measures, or says what comes next
}
canvas.addEventListener("pointerup", endPress);
canvas.addEventListener("pointercancel", endPress);
canvas.addEventListener("pointerleave", () => { if (!state.press) $("readout").classList.add("stale"); });
canvas.addEventListener("pointerenter", () => $("readout").classList.remove("stale"));
canvas.addEventListener("wheel", (ev) => {
  if (!state.frame) return;
  ev.preventDefault();
  if (state.mode === "live") freeze(); // zoom is on the frozen frame
  // a mouse wheel notch is ~100 px of deltaY: 1.25x per notch; a touchpad's pinch arrives as ctrl+wheel
  zoomAt(state.zoom.k * Math.exp(-ev.deltaY * (ev.ctrlKey ? 0.01 : 0.00223)), ev.clientX, ev.clientY);
}, { passive: false });
canvas.addEventListener("focus", draw);
canvas.addEventListener("blur", () => { state.nudging = false; draw(); });

// ---- keyboard placement ---------------------------------------------------------------------------
// With the image focused: Enter places two handles (when there are none) and measures; arrows nudge the
// active handle by one image pixel (Shift: 10); Tab goes to the other handle; Esc cancels.
async function keyboardPlace() {
  if (!state.frame) return;
  if (state.mode !== "frozen" && !(await freeze())) return;
  const w = canvas.width, h = canvas.height;
  const spots = [[Math.round(w / 3), Math.round(h / 2)], [Math.round((2 * w) / 3), Math.round(h / 2)]];
  if (state.points.length === 1) state.points.push(spots[1]);
  else state.points = spots;
  state.result = null;
  showResult(null);
  state.pointerTypes = ["mouse", "mouse"]; // a key moves by whole image pixels: no worse than a mouse
  state.active = 0;
  state.dirty = true;
  state.nudging = true;
  keepVisible(state.points[0]);
  queryDepth(state.points[0]);
  $("hint").textContent = "Arrows move the blue handle (Shift: 10 px), Tab the other one, Enter measures.";
  draw();
}

function nudge(dx, dy) {
  const i = Math.min(state.active, state.points.length - 1);
  const p = state.points[i];
  state.points[i] = clampToImage([p[0] + dx, p[1] + dy]);
  state.pointerTypes[i] = state.pointerTypes[i] || "mouse";
  state.dirty = true;
  state.nudging = true;
  keepVisible(state.points[i]);
  queryDepth(state.points[i]);
  draw();
}

function canvasKey(e) {
  const arrows = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, -1], ArrowDown: [0, 1] };
  if (e.key in arrows) {
    if (!state.points.length) { isShapeTool() ? keyboardAddPoint() : keyboardPlace(); return true; }
    const step = e.shiftKey ? 10 : 1;
    nudge(arrows[e.key][0] * step, arrows[e.key][1] * step);
    return true;
  }
  if (e.key === "Tab" && state.points.length >= 2) {
    // one focus stop per handle: Tab from the first handle to the next, then on out of the image
    const next = state.active + (e.shiftKey ? -1 : 1);
    if (next < 0 || next > state.points.length - 1) return false;
    state.active = next;
    state.nudging = true;
    keepVisible(state.points[next]);
    queryDepth(state.points[next]);
    draw();
    return true;
  }
  if (e.key === "Enter" && isShapeTool()) { shapeEnter(e.shiftKey); return true; } // tools.js
  if (e.key === "Enter") {
    if (state.points.length < 2) keyboardPlace();
    else if (state.dirty || !state.result) { state.nudging = false; measure(!!state.result); }
    return true;
  }
  if (e.key === "+" || e.key === "=" || e.key === "-") {
    const r = canvas.getBoundingClientRect();
    const c = state.points.length ? imageToClient(state.points[Math.min(state.active, state.points.length - 1)]) : [r.left + r.width / 2, r.top + r.height / 2];
    if (state.mode === "live") freeze();
    zoomAt(state.zoom.k * (e.key === "-" ? 1 / 1.5 : 1.5), c[0], c[1]);
    return true;
  }
  if (e.key === "0") { resetZoom(); draw(); return true; }
  return false;
}

// ---- measuring ----------------------------------------------------------------------------------
async function measure(adjusting) {
  if (state.points.length !== 2 || !state.frame) return;
  await optionsReady;
  if (state.mode !== "frozen" && !(await freeze())) return;
  const previous = adjusting && state.result ? state.result.id : null;
  const body = { frame_id: state.frame.id, p1: state.points[0], p2: state.points[1], options: { method: state.method, click_px: clickPx() } };
  if (state.frames > 1 && state.method === "robust") body.frames = state.frames; // pooling is the robust method's
  await submit("api/measure", body, previous, {
    done: () => { $("hint").textContent = state.press ? "" : "Drag a handle to adjust; a press elsewhere starts again."; },
    failed: () => { $("hint").textContent = "Place two points to measure."; },
  });
}

// POST a measurement (api/measure, or api/shapes from tools.js) of the points on screen and show its
// answer. An answer that a newer adjustment overtook is deleted unseen; `previous`, the history entry
// being adjusted, is replaced by the new one (adjusting adds no row per drag). `on.done` and
// `on.failed` set the hint after an answer or an error; `on.changed` runs when the request is sent
// and again after its answer or error (the shape tools' buttons follow it).
async function submit(path, body, previous, on) {
  const gen = state.gen;
  const seq = ++state.seq;
  const changed = on.changed || (() => {});
  state.dirty = false;
  if (state.saved) { state.saved = null; showSaved(); }
  $("hint").textContent = "Measuring…";
  changed();
  let res;
  try {
    res = await api(path, { method: "POST", body });
  } catch (e) {
    if (seq !== state.seq) return;
    state.result = null;
    showResult(null);
    showError(e.message);
    on.failed();
    changed();
    draw();
    return;
  }
  if (seq !== state.seq) {
    if (gen === state.gen) api(`api/measurements/${res.id}`, { method: "DELETE" }).catch(() => {});
    refreshHistory();
    return;
  }
  if (gen === state.gen) {
    state.result = res;
    showResult(res);
    on.done();
  }
  if (previous !== null && previous !== undefined) await api(`api/measurements/${previous}`, { method: "DELETE" }).catch(() => {});
  changed();
  await refreshHistory();
  draw();
}

function showError(message) {
  const el = $("error");
  el.textContent = message;
  el.classList.toggle("hidden", !message);
}

// What a reason of the core's verdict means for the person, and what to do about it. The core's
// phrases: "low matcher confidence along the segment", "few valid samples", "methods disagree by N %", "end point on a depth edge", "segment
// crosses several surfaces", "gap detected", "end point extrapolated", "uncertainty above N %".
const ADVICE = [
  [/confidence/i, "The matcher had little texture along the dashed orange stretch: measure on a textured part, or add light or texture (the Confidence view shows where)."],
  [/extrapolat|no depth/i, "Place the ends just inside the object's edges, where the depth view has colour."],
  [/edge|mixed/i, "Move the end a few pixels off the depth edge, onto the object itself."],
  [/few|valid|sparse|missing|hole/i, "Move closer or add light and texture so more of the segment has depth."],
  [/surface|piece|crease/i, "Keep both ends on one flat surface, or measure each piece on its own."],
  [/gap/i, "The segment spans a gap: check in the depth view that both ends are on the objects you mean."],
  [/disagree|methods|model/i, "Re-place the ends carefully and compare with method “basic”."],
  [/uncertainty|far|distance|range|resolution|quantiz/i, "Move closer: the depth error grows with the square of the distance."],
];

function adviceFor(reasons, table = ADVICE, fallback = "Look at the segment in the depth view and measure again.") {
  const out = [];
  for (const r of reasons) {
    const hit = table.find(([re]) => re.test(r));
    const text = hit ? hit[1] : fallback;
    if (!out.includes(text)) out.push(text);
  }
  return out;
}

// Whether an end point's depth was measured there or extrapolated along the fitted line, as the
// core's verdict defines it: extrapolated when the nearest inlier sample is more than 5 px and more
// than 15 % of the segment's length away from the click.
function endState(res, i) {
  const explicit = res[`p${i + 1}_extrapolated`];
  if (typeof explicit === "boolean") return explicit ? "extrapolated" : "measured";
  const ends = res.ends && res.ends[i];
  if (ends && typeof ends.extrapolated === "boolean") return ends.extrapolated ? "extrapolated" : "measured";
  if (!res.samples_px || !res.support) return "unknown";
  const p = i === 0 ? res.p1 : res.p2;
  if (!p) return "unknown";
  const length = Math.hypot(res.p2[0] - res.p1[0], res.p2[1] - res.p1[1]);
  let nearest = Infinity;
  res.samples_px.forEach(([x, y], k) => { if (res.support[k]) nearest = Math.min(nearest, Math.hypot(x - p[0], y - p[1])); });
  return nearest > Math.max(5, 0.15 * length) ? "extrapolated" : "measured";
}

// What a history record says about where it came from: "replay desk · frame 3", or the live source.
function sourceLabel(m) {
  const kind = m.source_kind || "";
  const index = m.frame_index !== undefined && m.frame_index !== null ? ` · frame ${m.frame_index + 1}` : "";
  if (["replay", "bag", "video"].includes(kind)) return `${kind} ${m.recording || ""}`.trim() + index;
  return kind || m.source;
}

// When a history record was made (s since the epoch); shape rows may call it created_at.
function created(m) {
  return m.created !== undefined ? m.created : m.created_at;
}

// A reopened measurement is marked as the saved one, with when and where it was made.
function showSaved() {
  const el = $("saved");
  const m = state.saved;
  el.classList.toggle("hidden", !m);
  el.dataset.id = m ? String(m.id) : "";
  if (m) el.textContent = `Saved measurement #${m.id}${m.name ? " “" + m.name + "”" : ""} · ${new Date(created(m) * 1000).toLocaleString()} · ${sourceLabel(m)}`;
  updateTag();
}

function showResult(res) {
  if (!res || !state.saved || res.id !== state.saved.id) state.saved = null;
  showSaved();
  showError("");
  $("save-png").disabled = !res;
  if (showShapeCard(res)) return; // tools.js: a shape's card
  const d = $("distance");
  if (!res) {
    d.textContent = "—";
    d.dataset.metres = "";
    delete d.dataset.id;
    d.className = "distance";
    const iv = $("interval");
    iv.innerHTML = "&nbsp;";
    iv.dataset.low = iv.dataset.high = "";
    $("verdict").className = "verdict hidden";
    $("why").classList.add("hidden");
    $("ends").replaceChildren();
    for (const id of ["r-method", "r-fit", "r-samples", "r-basic", "r-sigma", "r-frames", "r-time"]) $(id).textContent = "—";
    $("warnings").replaceChildren();
    return;
  }
  d.textContent = fmt(res.distance_m);
  d.dataset.metres = res.distance_m === null ? "" : String(res.distance_m);
  d.dataset.id = String(res.id);
  const iv = interval95(res);
  const ivEl = $("interval");
  ivEl.textContent = fmtInterval(res) + (iv ? (iv.from === "interval" ? " · 95 % interval" : " · 95 % (±1.96σ)") : "");
  ivEl.dataset.low = iv ? String(iv.lo) : "";
  ivEl.dataset.high = iv ? String(iv.hi) : "";
  showVerdict(res.quality, (res.reasons || []).map((r) => (typeof r === "string" ? r : r.message || r.code || JSON.stringify(r))));
  const ends = [0, 1].map((i) => {
    const p3 = i === 0 ? res.p1_m : res.p2_m;
    const st = endState(res, i);
    const row = document.createElement("div");
    row.className = `end end-${st}`;
    row.dataset.state = st;
    row.innerHTML = `<b>P${i + 1}</b> <span class="end-depth"></span> <span class="end-state"></span><div class="end-xyz muted"></div>`;
    row.querySelector(".end-depth").textContent = `depth ${p3 && p3[2] !== null ? fmt(p3[2]) : "—"}`;
    row.querySelector(".end-state").textContent = st;
    row.querySelector(".end-xyz").textContent = `XYZ ${fmtPoint3(p3)}`;
    return row;
  });
  $("ends").replaceChildren(...ends);
  $("r-method").textContent = res.method;
  $("r-fit").textContent = res.fit;
  $("r-samples").textContent = `${res.n_support} / ${res.n_valid} (of ${res.n_samples})`;
  $("r-basic").textContent = fmt(res.basic_distance_m);
  $("r-sigma").textContent = res.uncertainty_m === null ? "—" : fmtSmall(res.uncertainty_m);
  $("r-time").textContent = `${res.elapsed_ms.toFixed(1)} ms`;
  // several frames: how many were pooled, and how much narrower than the newest frame alone
  const used = res.frames_used || 1;
  const gain = res.single_frame_uncertainty_m && res.uncertainty_m ? res.single_frame_uncertainty_m / res.uncertainty_m : null;
  $("r-frames").textContent = res.frames_requested > 1
    ? `${used} of ${res.frames_requested} used` + (gain ? ` · 1σ ${gain.toFixed(2)}× narrower than one frame` : "")
    : "1";
  const warnings = [...res.warnings];
  if (res.gap_detected && !warnings.some((w) => /gap/i.test(w))) warnings.unshift("gap detected between the end points");
  $("warnings").replaceChildren(...warnings.map((w) => Object.assign(document.createElement("li"), { textContent: w })));
}

// The verdict pill, the value's colour, and when not good why and what to do (`table`: reason
// patterns and advice, `fallback` for a reason none matches); good with notes: the notes.
function showVerdict(q, reasons, table = ADVICE, fallback = undefined) {
  const d = $("distance");
  const verdict = $("verdict");
  if (q) {
    verdict.className = `verdict v-${q}`;
    verdict.textContent = q === "good" ? "✓ good" : q === "check" ? "⚠ check" : "✕ unreliable";
    verdict.title = reasons.join("\n");
    d.className = `distance d-${q}`;
  } else {
    verdict.className = "verdict hidden"; // a service without verdicts: the warnings below still say what they can
    d.className = "distance";
  }
  const notGood = q && q !== "good";
  $("why").classList.toggle("hidden", !(notGood || reasons.length));
  $("why").classList.toggle("notes", !notGood);
  const rs = reasons.length || !notGood ? reasons : ["the service gave no reason"];
  $("reasons").replaceChildren(...rs.map((r) => Object.assign(document.createElement("li"), { textContent: r })));
  $("advice").replaceChildren(...(notGood ? adviceFor(rs, table, fallback) : []).map((a) => Object.assign(document.createElement("li"), { textContent: a })));
}

function clearPoints() {
  state.points = [];
  state.result = null;
  state.press = null;
  state.dirty = false;
  state.nudging = false;
  state.saved = null;
  state.seq++;
  loupe.classList.add("hidden");
  showResult(null);
  $("hint").textContent = toolSpec().hint;
  showToolButtons(); // tools.js
  draw();
}

// ---- the annotated PNG ---------------------------------------------------------------------------
// The measured frame's colour image at its own resolution (the exact PNG, also when the view shows
// depth) with the segment, the value, the interval and the verdict drawn on it, built in the page.
function annotatedCanvas(img) {
  const res = state.result;
  const out = document.createElement("canvas");
  out.width = img.naturalWidth;
  out.height = img.naturalHeight;
  const c = out.getContext("2d");
  c.drawImage(img, 0, 0);
  const s = Math.max(1, out.width / 900);
  if (isShape(res)) annotateShape(c, res, s); // tools.js
  else {
    const pts = [res.p1, res.p2].map(([x, y]) => [x + 0.5, y + 0.5]);
    drawSegment(c, pts, s);
    if (Array.isArray(res.weak_stretches) && res.weak_stretches.length) drawWeak(c, pts, s, res.weak_stretches);
    pts.forEach(([x, y]) => drawHandle(c, x, y, s, false));
    const iv = interval95(res);
    const sub = [iv ? `95 %: ${fmt(iv.lo, false)} – ${fmt(iv.hi)}` : "uncertainty unknown", res.quality || ""].filter(Boolean).join(" · ");
    drawLabel(c, pts, s, fmtInterval(res), verdictColor(res.quality), sub);
  }
  c.font = `${Math.round(12 * s)}px system-ui, sans-serif`;
  c.textAlign = "left"; c.textBaseline = "bottom";
  const footer = `depthruler · measurement ${res.id}${isShape(res) ? " (" + res.kind + ")" : ""} · ${sourceLabel(res)} · frame id ${res.frame_id} · ${new Date(created(res) * 1000).toISOString()}`;
  c.fillStyle = "rgba(0,0,0,.6)"; c.fillRect(0, out.height - 20 * s, out.width, 20 * s);
  c.fillStyle = "#e6e9ee"; c.fillText(footer, 6 * s, out.height - 4 * s);
  return out;
}

async function savePng() {
  if (!state.result || !state.frame || state.mode !== "frozen") return;
  const res = state.result;
  let img;
  try {
    img = await loadImage(`api/frames/${state.frame.id}/color.png`); // exact pixels, whatever the view shows
  } catch (e) {
    showError(e.message);
    return;
  }
  annotatedCanvas(img).toBlob((blob) => {
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = `depthruler-${res.id}${res.name ? "-" + res.name.replace(/[^\w.-]+/g, "_") : ""}.png`;
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
  }, "image/png");
}

// ---- history ------------------------------------------------------------------------------------
async function refreshHistory() {
  let items = [];
  try { items = await api("api/measurements?limit=100"); } catch (e) { return; }
  state.history = items;
  renderHistory();
}

function renderHistory() {
  const pending = state.pendingDelete ? state.pendingDelete.record.id : null;
  const items = state.history.filter((m) => m.id !== pending);
  const sources = [...new Set(items.map((m) => m.source))].sort();
  const sel = $("history-filter");
  const keep = state.filter;
  sel.replaceChildren(new Option("all", ""), ...sources.map((s) => new Option(s.length > 40 ? s.slice(0, 38) + "…" : s, s)));
  sel.value = sources.includes(keep) ? keep : "";
  state.filter = sel.value;
  const shown = items.filter((m) => !state.filter || m.source === state.filter);
  $("history").replaceChildren(...shown.map(historyItem));
  $("history-empty").classList.toggle("hidden", shown.length > 0);
  $("csv").href = withToken(`api/measurements.csv?units=${state.units}`);
  $("json").href = withToken("api/measurements.json");
}

function historyItem(m) {
  const li = document.createElement("li");
  li.dataset.id = m.id;
  li.dataset.kind = kindLabel(m); // tools.js
  const img = Object.assign(document.createElement("img"), { src: withToken(`api/measurements/${m.id}/thumb.png`), alt: "" });
  const text = document.createElement("div");
  text.className = "h-text";
  const when = new Date(created(m) * 1000).toLocaleTimeString();
  text.innerHTML = `<div class="h-name"></div><div class="h-dist"></div><div class="h-meta"></div><div class="h-note"></div>`;
  text.querySelector(".h-name").textContent = m.name || "";
  text.querySelector(".h-dist").textContent = isShape(m) ? shapeSummary(m) : m.distance_m === null ? "—" : fmtInterval(m);
  if (m.quality) {
    const dot = Object.assign(document.createElement("span"), { className: `qdot v-${m.quality}`, title: m.quality });
    text.querySelector(".h-dist").prepend(dot);
  }
  const warnings = m.warnings || [];
  const method = m.method || (m.options && m.options.method) || "";
  text.querySelector(".h-meta").textContent = [isShape(m) ? kindLabel(m) : "", sourceLabel(m), method, when].filter(Boolean).join(" · ") + (warnings.length ? " · ⚠ " + warnings.length : "");
  text.querySelector(".h-meta").title = [...(m.reasons || []), ...warnings].join("\n");
  text.querySelector(".h-note").textContent = m.note || "";
  const edit = Object.assign(document.createElement("button"), { className: "h-btn h-edit", title: "Name and note", textContent: "✎" });
  edit.addEventListener("click", (ev) => { ev.stopPropagation(); editItem(li, m); });
  const del = Object.assign(document.createElement("button"), { className: "h-btn h-del", title: "Delete", textContent: "×" });
  del.addEventListener("click", (ev) => { ev.stopPropagation(); deleteWithUndo(m); });
  const buttons = document.createElement("div");
  buttons.className = "h-buttons";
  buttons.append(edit, del);
  li.addEventListener("click", () => reopen(m.id));
  li.append(img, text, buttons);
  return li;
}

function editItem(li, m) {
  const form = document.createElement("form");
  form.className = "h-form";
  form.innerHTML = `<input name="name" maxlength="200" placeholder="Name (e.g. kitchen door width)"><textarea name="note" maxlength="4000" rows="2" placeholder="Note"></textarea><div><button class="btn small primary" type="submit">Save</button> <button class="btn small" type="button">Cancel</button></div>`;
  form.name.value = m.name || "";
  form.note.value = m.note || "";
  form.addEventListener("click", (ev) => ev.stopPropagation());
  form.querySelector("button[type=button]").addEventListener("click", () => renderHistory());
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    try {
      const rec = await api(`api/measurements/${m.id}`, { method: "PATCH", body: { name: form.name.value.trim(), note: form.note.value.trim() } });
      if (state.result && state.result.id === m.id) { state.result.name = rec.name; state.result.note = rec.note; }
      await refreshHistory();
    } catch (e) { showError(e.message); }
  });
  li.replaceChildren(form);
  form.name.focus();
}

// Deleting hides the entry at once and deletes it on the server only when the undo time has passed
// (or another deletion starts), so Undo needs no server-side trash.
function deleteWithUndo(m) {
  commitPendingDelete();
  const timer = setTimeout(commitPendingDelete, UNDO_MS);
  state.pendingDelete = { record: m, timer };
  $("undo-text").textContent = `Deleted ${m.name ? "“" + m.name + "”" : isShape(m) ? shapeValueText(m) : fmt(m.distance_m)}.`;
  $("undo").classList.remove("hidden");
  if (state.result && state.result.id === m.id) clearPoints();
  renderHistory();
}

function commitPendingDelete() {
  const p = state.pendingDelete;
  if (!p) return;
  clearTimeout(p.timer);
  state.pendingDelete = null;
  $("undo").classList.add("hidden");
  // keepalive: the deletion still goes out when it is committed because the page is being left
  api(`api/measurements/${p.record.id}`, { method: "DELETE", keepalive: true }).catch((e) => showError(e.message)).then(refreshHistory);
}

function undoDelete() {
  const p = state.pendingDelete;
  if (!p) return;
  clearTimeout(p.timer);
  state.pendingDelete = null;
  $("undo").classList.add("hidden");
  renderHistory();
}

// Reopen a measurement on its saved frame; until that frame is on screen the page is "freezing",
// so a click meanwhile waits for it instead of landing on the frame being replaced.
function reopen(id) {
  const previous = state.mode === "frozen" ? state.frame : null;
  const gen = ++state.gen;
  state.mode = "freezing";
  updateFreezeButton();
  updateTag();
  state.freezing = (async () => {
    try {
      const { frame } = await api(`api/measurements/${id}/open`, { method: "POST" });
      const measurement = await api(`api/measurements/${id}`); // the per-sample arrays live here
      if (gen !== state.gen) return false;
      if (previous && previous.id !== frame.id) api(`api/frames/${previous.id}/freeze`, { method: "DELETE" }).catch(() => {});
      if (!(await showFrame(frame, gen))) return false;
      state.mode = "frozen";
      resetZoom();
      state.saved = measurement;
      applyTool(isShape(measurement) ? measurement.kind : "distance"); // tools.js: the tool it was made with
      state.points = isShape(measurement) ? measurement.points.map((p) => p.slice()) : [measurement.p1, measurement.p2];
      state.pointerTypes = [];
      state.dirty = false;
      state.result = measurement;
      state.seq++;
      updateFreezeButton();
      updateTag();
      showResult(measurement);
      showToolButtons();
      draw();
      return true;
    } catch (e) {
      if (gen === state.gen) { showError(e.message); state.mode = "live"; state.gen++; updateFreezeButton(); updateTag(); liveLoop(); }
      return false;
    }
  })();
  return state.freezing;
}

// ---- source: badge, status, replay controls, recording ------------------------------------------
function sourceBadge(s) {
  const kind = s.kind || (s.spec || "").split(":")[0];
  if (kind === "replay" || kind === "bag" || kind === "video") return [kind, `${kind.toUpperCase()} ${(s.replay && s.replay.recording) || s.name || ""}`.trim()];
  if (kind === "sim") return ["sim", "SIMULATOR"];
  if (!kind) return ["", "source"];
  const fps = s.fps ? ` · ${(+s.fps).toFixed(0)} fps` : "";
  return ["camera", `${kind.toUpperCase()} ${s.name || ""}${s.serial ? " " + s.serial : ""}${fps}`.trim()];
}

async function pollSource() {
  const pill = $("source-status");
  const msg = $("stage-msg");
  try {
    const s = await api("api/source");
    state.source = s;
    const [cls0, badge] = sourceBadge(s);
    const b = $("source-badge");
    b.className = `badge badge-${cls0}`;
    b.textContent = badge;
    b.title = s.replay ? `${s.replay.kind} ${s.replay.recording}${s.replay.recorded_source ? " of " + s.replay.recorded_source : ""} (${s.replay.frames || "?"} frames)` : `${s.name || ""} ${s.spec || ""}`.trim();
    b.dataset.kind = cls0;
    const size = s.width ? ` · ${s.width}×${s.height}` : "";
    const fps = s.measured_fps ? ` · ${s.measured_fps.toFixed(1)} fps` : s.fps ? ` · ${s.fps} fps` : "";
    let cls = "pill-ok", text = `${s.state}${size}${fps}`;
    if (s.state === "disconnected" || s.state === "reconnecting") {
      cls = "pill-bad";
      const retry = s.retry_in_s > 0.5 ? ` — retrying in ${Math.ceil(s.retry_in_s)} s` : " — reconnecting…";
      text = `${s.state}${retry}`;
      msg.textContent = `Source ${s.state}: ${s.message || "no frames"}${retry}`;
    } else if (s.state === "ended") {
      cls = "pill-wait";
      text = "ended · last frame kept";
    } else if (s.state !== "streaming") {
      cls = "pill-wait";
      text = `${s.state}…`;
    } else if (s.replay && s.replay.paused) {
      cls = "pill-wait";
      text = `paused${size}`;
    }
    msg.classList.toggle("hidden", cls !== "pill-bad" || state.mode !== "live");
    pill.className = "pill " + cls;
    pill.textContent = text;
    pill.title = s.message || s.spec;
    setRecording(s.recording);
    showReplay(s.replay);
    $("replay-home").classList.toggle("hidden", !s.home);
    $("replay-home").title = s.home ? `Stop the replay and go back to ${s.home}` : "";
  } catch (e) {
    pill.className = "pill pill-bad";
    pill.textContent = "service unreachable";
    pill.title = e.message;
  }
}

function showReplay(r) {
  const bar = $("replay-bar");
  bar.classList.toggle("hidden", !r);
  if (!r) return;
  $("replay-play").textContent = r.paused ? "Play" : "Pause";
  bar.dataset.paused = r.paused ? "1" : "";
  $("replay-scrub").max = String(Math.max(0, r.frames - 1));
  $("replay-scrub").disabled = !(r.frames > 0); // a video that does not list its frames: pause and step only
  $("replay-pos").dataset.frames = String(r.frames);
  showReplayPosition();
}

// The replay position is that of the frame on screen (the stream may be ahead of it).
function showReplayPosition() {
  const pos = $("replay-pos");
  const f = state.frame;
  const r = state.source && state.source.replay;
  const index = f && f.replay_index !== null && f.replay_index !== undefined ? f.replay_index : r ? r.index : null;
  const scrub = $("replay-scrub");
  if (document.activeElement !== scrub && index !== null) scrub.value = String(index);
  pos.textContent = index === null ? "—" : framePosition(index, Number(pos.dataset.frames) || 0);
  pos.dataset.index = index === null ? "" : String(index);
}

async function replay(action, index) {
  if (!state.source || !state.source.replay) return;
  if (state.mode !== "live") goLive(); // the replay drives the live view
  try {
    showReplay(await api("api/source/replay", { method: "POST", body: index === undefined ? { action } : { action, index } }));
  } catch (e) {
    showError(e.message);
  }
}

function replayStep(delta) {
  const r = state.source && state.source.replay;
  if (!r) return;
  if (delta > 0) return replay("step");
  const now = state.frame && state.frame.replay_index !== null && state.frame.replay_index !== undefined ? state.frame.replay_index : r.index;
  return replay("seek", now > 0 ? now - 1 : Math.max(0, r.frames - 1)); // from the first frame back to the last
}

function setRecording(rec) {
  state.recording = !!(rec && rec.active);
  const b = $("record");
  b.classList.toggle("on", state.recording);
  $("record-label").textContent = state.recording ? `Stop (${rec.frames})` : "Record";
  b.title = rec && rec.path ? `${rec.active ? "Recording to" : "Last recording:"} ${rec.path}${rec.error ? " — " + rec.error : ""}` : "Start/stop recording (r)";
}

async function toggleRecording() {
  const stopping = state.recording;
  try {
    const rec = await api("api/recordings", { method: "POST", body: { action: stopping ? "stop" : "start" } });
    setRecording(rec);
    if (stopping && rec.path) recordingToast(rec);
  } catch (e) {
    showError(e.message);
  }
}

// Where the recording went, said when it stops: its folder (copyable) and how to play it back.
function recordingToast(rec) {
  const toast = $("toast");
  const command = `depthruler serve --source replay:${rec.path}`;
  toast.dataset.path = rec.path;
  $("toast-text").textContent = `Recorded ${rec.frames} frame${rec.frames === 1 ? "" : "s"} to`;
  $("toast-path").textContent = rec.path;
  const open = $("toast-open");
  open.dataset.name = rec.path.split("/").pop();
  open.title = `Play it back here, in place of the live source until "Back to live source"; or run: ${command}`;
  toast.classList.remove("hidden");
  clearTimeout(state.toastTimer);
  state.toastTimer = setTimeout(() => toast.classList.add("hidden"), 20000);
}

// Play a recording of the server's recordings root in its source's place (null: back to that source).
async function openSource(recording) {
  try {
    goLive();
    const s = await api("api/source", { method: "POST", body: { recording } });
    $("toast").classList.add("hidden");
    state.source = s;
    pollSource();
  } catch (e) {
    showError(e.message);
  }
}

async function copyPath() {
  const path = $("toast").dataset.path || "";
  try { await navigator.clipboard.writeText(path); $("toast-copy").textContent = "Copied"; } catch (e) {
    // no clipboard (plain http on another host): select the text so the person can copy it
    const r = document.createRange(); r.selectNodeContents($("toast-path"));
    const sel = window.getSelection(); sel.removeAllRanges(); sel.addRange(r);
  }
}

// ---- controls -----------------------------------------------------------------------------------
function setUnits(u) {
  state.units = u;
  localStorage.setItem("depthruler-units", u);
  $("units").value = u;
  showResult(state.result);
  renderHistory();
  drawColorbar();
  if (state.hoverDepth) showDepth(state.hoverDepth);
  draw();
}

function setMethod(m) {
  state.method = m;
  localStorage.setItem("depthruler-method", m);
  $("method").value = m;
  remeasure(); // tools.js: the measurement on screen, with the new method
}

$("units").addEventListener("change", (e) => setUnits(e.target.value));
$("method").addEventListener("change", (e) => setMethod(e.target.value));
state.frames = Number(localStorage.getItem("depthruler-frames")) || 1;
$("frames").value = String(state.frames);
$("frames").addEventListener("change", (e) => {
  state.frames = Number(e.target.value) || 1;
  localStorage.setItem("depthruler-frames", String(state.frames));
  if (!isShapeTool() && state.points.length === 2) measure(true); // pooling is the segment's
});
$("freeze").addEventListener("click", () => (state.mode === "live" ? freeze() : goLive()));
$("view-color").addEventListener("click", () => setView("color"));
$("view-disparity").addEventListener("click", () => setView("disparity"));
$("view-confidence").addEventListener("click", () => setView("confidence"));
$("clear").addEventListener("click", clearPoints);
$("read-depth").addEventListener("click", () => setReadMode(!state.readMode));
$("zoom-reset").addEventListener("click", () => { resetZoom(); draw(); });
$("record").addEventListener("click", toggleRecording);
$("save-png").addEventListener("click", savePng);
$("undo-btn").addEventListener("click", undoDelete);
$("toast-open").addEventListener("click", () => openSource($("toast-open").dataset.name));
$("toast-copy").addEventListener("click", copyPath);
$("toast-close").addEventListener("click", () => $("toast").classList.add("hidden"));
$("replay-home").addEventListener("click", () => openSource(null));
$("history-filter").addEventListener("change", (e) => { state.filter = e.target.value; renderHistory(); });
$("replay-play").addEventListener("click", () => replay(state.source && state.source.replay && state.source.replay.paused ? "play" : "pause"));
$("replay-step").addEventListener("click", () => replayStep(1));
$("replay-back").addEventListener("click", () => replayStep(-1));
$("replay-scrub").addEventListener("change", (e) => replay("seek", Number(e.target.value)));
window.addEventListener("pagehide", commitPendingDelete);

document.addEventListener("keydown", (e) => {
  if (["SELECT", "INPUT", "TEXTAREA"].includes(e.target.tagName) || e.ctrlKey || e.metaKey || e.altKey) return;
  if (e.target === canvas && canvasKey(e)) { e.preventDefault(); return; }
  const keys = Object.keys(UNITS);
  switch (e.key) {
    case "Escape":
      if (state.press || state.points.length) clearPoints(); else if (state.zoom.k > 1) { resetZoom(); draw(); } else goLive();
      break;
    case "f": state.mode === "live" ? freeze() : goLive(); break;
    case "d": setView(state.view === "color" ? "disparity" : "color"); break;
    case "c": setView(state.view === "confidence" ? "color" : "confidence"); break;
    case "u": setUnits(keys[(keys.indexOf(state.units) + 1) % keys.length]); break;
    case "m": if (OPTIONS.methods.length) setMethod(OPTIONS.methods[(OPTIONS.methods.indexOf(state.method) + 1) % OPTIONS.methods.length]); break;
    case "r": toggleRecording(); break;
    case ".": replayStep(1); break;
    case ",": replayStep(-1); break;
    case " ": // held: the mouse pans; tapped alone: pause / play a replay (a focused button takes space itself)
      if (e.target.tagName === "BUTTON") return;
      if (!state.space.down) Object.assign(state.space, { down: true, used: false });
      canvas.style.cursor = "grab";
      break;
    default:
      if (!toolKey(e)) return; // tools.js: l p a h b, Backspace, Enter
      break;
  }
  e.preventDefault();
});
document.addEventListener("keyup", (e) => {
  if (e.key !== " " || !state.space.down) return;
  const used = state.space.used;
  Object.assign(state.space, { down: false, used: false });
  canvas.style.cursor = "crosshair";
  if (!used && state.source && state.source.replay && e.target.tagName !== "BUTTON") $("replay-play").click();
});
window.addEventListener("resize", () => { fitCanvas(); draw(); });

$("units").value = state.units in UNITS ? state.units : (state.units = "m");

// The methods, the default method and the limits, as the core describes them (retried until the API answers).
async function loadOptions() {
  for (;;) {
    try {
      const o = await api("api/options");
      const field = (name) => o.fields.find((f) => f.name === name);
      OPTIONS.methods = o.methods;
      OPTIONS.clickMax = field("click_px").max;
      OPTIONS.framesMax = o.frames.max;
      $("method").replaceChildren(...o.methods.map((m) => new Option(m, m)));
      $("method").value = o.methods.includes(state.method) ? state.method : (state.method = field("method").default);
      for (const opt of [...$("frames").options]) if (Number(opt.value) > OPTIONS.framesMax) opt.remove();
      if (state.frames > OPTIONS.framesMax) state.frames = 1;
      $("frames").value = String(state.frames);
      return;
    } catch (err) {
      await new Promise((resolve) => setTimeout(resolve, 1000));
    }
  }
}
const optionsReady = loadOptions();
initTools(); // tools.js
fitCanvas();
pollSource();
liveLoop();
refreshHistory();
setInterval(pollSource, 1000);
