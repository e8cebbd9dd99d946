// depthruler web page: live view, freeze, click two points, measure, history. Plain JS, no build.
"use strict";

const UNITS = { m: [1, 3], cm: [100, 1], mm: [1000, 0], in: [1 / 0.0254, 2] }; // factor, decimals
const METHODS = ["robust", "paper", "basic"];
const HANDLE_PX = 16; // screen pixels within which a press grabs an end point

const $ = (id) => document.getElementById(id);
const canvas = $("canvas");
const ctx = canvas.getContext("2d");

const state = {
  token: new URLSearchParams(location.search).get("token") || sessionStorage.getItem("depthruler-token") || "",
  frame: null,        // frame JSON of the image on screen
  img: null,          // its decoded image
  frozen: false,
  view: "color",
  points: [],         // [[x, y], ...] in image pixels
  result: null,       // the last measurement record
  drag: -1,
  units: localStorage.getItem("depthruler-units") || "m",
  method: localStorage.getItem("depthruler-method") || "robust",
  loading: false,
  recording: false,
};

// ---- HTTP ---------------------------------------------------------------------------------------
function withToken(url) {
  if (!state.token) return url;
  return url + (url.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(state.token);
}

async function api(path, options = {}) {
  const headers = Object.assign({}, options.headers || {});
  if (state.token) headers.Authorization = "Bearer " + state.token;
  // The server refuses state changes without a JSON content type (a cross-site form cannot send one).
  if ((options.method || "GET") !== "GET") headers["Content-Type"] = "application/json";
  if (options.body && typeof options.body !== "string") {
    headers["Content-Type"] = "application/json";
    options = Object.assign({}, options, { body: JSON.stringify(options.body) });
  }
  const res = await fetch(path, Object.assign({}, options, { headers }));
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

// ---- formatting ---------------------------------------------------------------------------------
function fmt(metres, withUnit = true) {
  if (metres === null || metres === undefined || !isFinite(metres)) return "—";
  const [k, dec] = UNITS[state.units];
  return (metres * k).toFixed(dec) + (withUnit ? " " + state.units : "");
}

function fmtPlusMinus(metres) {
  // Two significant digits however small the uncertainty is, never fewer decimals than the distance.
  const [k, dec] = UNITS[state.units];
  const v = metres * k;
  const digits = v > 0 ? Math.min(6, Math.max(dec, Math.ceil(-Math.log10(v)) + 1)) : dec;
  return "± " + v.toFixed(digits) + " " + state.units;
}

function fmtUncertainty(metres) {
  if (metres === null || metres === undefined || !isFinite(metres)) return "uncertainty unknown";
  return fmtPlusMinus(metres) + " (1σ)";
}

// ---- frames -------------------------------------------------------------------------------------
async function showFrame(frame) {
  const img = await loadImage(`api/frames/${frame.id}/${state.view}.png`);
  if (canvas.width !== img.naturalWidth || canvas.height !== img.naturalHeight) {
    canvas.width = img.naturalWidth;
    canvas.height = img.naturalHeight;
    fitCanvas();
  }
  state.frame = frame;
  state.img = img;
  canvas.dataset.frameId = String(frame.id);
  $("frame-tag").textContent = `${state.frozen ? "frozen" : "live"} · frame ${frame.id} · ${frame.width}×${frame.height}`;
  draw();
}

async function pollLive() {
  if (state.frozen || state.loading || document.hidden) return;
  state.loading = true;
  try {
    const frame = await api("api/frames/latest");
    if (!state.frozen && (!state.frame || frame.id !== state.frame.id)) await showFrame(frame);
  } catch (e) {
    /* the status pill reports source problems */
  } finally {
    state.loading = false;
  }
}

async function freeze() {
  if (state.frozen || !state.frame) return;
  state.frozen = true;
  updateFreezeButton();
  try {
    const f = await api(`api/frames/${state.frame.id}/freeze`, { method: "POST" });
    state.frame = f;
    $("frame-tag").textContent = `frozen · frame ${f.id} · ${f.width}×${f.height}`;
  } catch (e) {
    showError(e.message);
  }
}

function goLive() {
  if (!state.frozen) return;
  if (state.frame) api(`api/frames/${state.frame.id}/freeze`, { method: "DELETE" }).catch(() => {});
  state.frozen = false;
  clearPoints();
  updateFreezeButton();
  pollLive();
}

function updateFreezeButton() {
  const b = $("freeze");
  b.textContent = state.frozen ? "Go live" : "Freeze";
  b.classList.toggle("frozen", state.frozen);
}

async function setView(view) {
  state.view = view;
  $("view-color").classList.toggle("active", view === "color");
  $("view-disparity").classList.toggle("active", view === "disparity");
  if (state.frame) {
    try { await showFrame(state.frame); } catch (e) { showError(e.message); }
  }
}

// ---- drawing ------------------------------------------------------------------------------------
function fitCanvas() {
  // The largest size with the image's aspect ratio that fits the stage's width and the window's height.
  const stage = $("stage");
  const maxW = stage.clientWidth;
  const maxH = Math.max(200, window.innerHeight - stage.getBoundingClientRect().top - 40);
  const k = Math.min(maxW / canvas.width, maxH / canvas.height);
  canvas.style.width = `${Math.floor(canvas.width * k)}px`;
  canvas.style.height = `${Math.floor(canvas.height * k)}px`;
}

function screenScale() {
  const r = canvas.getBoundingClientRect();
  return r.width > 0 ? canvas.width / r.width : 1;
}

function draw() {
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (state.img) ctx.drawImage(state.img, 0, 0);
  const s = screenScale();
  const res = state.result;
  const pts = state.points.map(([x, y]) => [x + 0.5, y + 0.5]);
  if (pts.length === 2) {
    ctx.lineCap = "round";
    ctx.strokeStyle = "rgba(0,0,0,.65)";
    ctx.lineWidth = 5 * s;
    ctx.beginPath(); ctx.moveTo(...pts[0]); ctx.lineTo(...pts[1]); ctx.stroke();
    ctx.strokeStyle = "#ffc94d";
    ctx.lineWidth = 2.2 * s;
    ctx.beginPath(); ctx.moveTo(...pts[0]); ctx.lineTo(...pts[1]); ctx.stroke();
  }
  if (res && res.samples_px && state.points.length === 2) {
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
  for (const [x, y] of pts) {
    ctx.lineWidth = 2 * s;
    ctx.strokeStyle = "#000";
    ctx.fillStyle = "rgba(255,201,77,.35)";
    ctx.beginPath(); ctx.arc(x, y, 9 * s, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
    ctx.strokeStyle = "#ffc94d";
    ctx.lineWidth = 1.5 * s;
    ctx.beginPath(); ctx.moveTo(x - 13 * s, y); ctx.lineTo(x + 13 * s, y); ctx.moveTo(x, y - 13 * s); ctx.lineTo(x, y + 13 * s); ctx.stroke();
  }
  if (res && pts.length === 2 && state.drag < 0) {
    const label = fmt(res.distance_m);
    const mx = (pts[0][0] + pts[1][0]) / 2, my = (pts[0][1] + pts[1][1]) / 2;
    ctx.font = `600 ${Math.round(16 * s)}px system-ui, sans-serif`;
    const w = ctx.measureText(label).width + 16 * s, h = 26 * s;
    ctx.fillStyle = "rgba(15,18,22,.85)";
    ctx.beginPath(); ctx.roundRect(mx - w / 2, my - h - 10 * s, w, h, 6 * s); ctx.fill();
    ctx.fillStyle = "#ffc94d";
    ctx.textAlign = "center"; ctx.textBaseline = "middle";
    ctx.fillText(label, mx, my - h / 2 - 10 * s);
  }
}

// ---- pointer input (mouse, pen and touch) -------------------------------------------------------
function toImage(ev) {
  const r = canvas.getBoundingClientRect();
  const x = (ev.clientX - r.left) * (canvas.width / r.width) - 0.5;
  const y = (ev.clientY - r.top) * (canvas.height / r.height) - 0.5;
  return [Math.min(Math.max(x, 0), canvas.width - 1), Math.min(Math.max(y, 0), canvas.height - 1)];
}

function handleAt(p) {
  const limit = HANDLE_PX * screenScale();
  let best = -1, bestD = limit;
  state.points.forEach(([x, y], i) => {
    const d = Math.hypot(x - p[0], y - p[1]);
    if (d <= bestD) { best = i; bestD = d; }
  });
  return best;
}

canvas.addEventListener("pointerdown", async (ev) => {
  if (!state.frame || ev.button > 0) return;
  ev.preventDefault();
  canvas.focus();
  const p = toImage(ev);
  const grab = handleAt(p);
  if (grab >= 0 && state.points.length === 2) {
    state.drag = grab;
    canvas.setPointerCapture(ev.pointerId);
    return;
  }
  if (!state.frozen) await freeze();
  if (state.points.length >= 2) { state.points = []; state.result = null; showResult(null); }
  state.points.push(p);
  draw();
  if (state.points.length === 2) measure(false);
  else $("hint").textContent = "Now click the second point (Esc cancels).";
});

canvas.addEventListener("pointermove", (ev) => {
  const p = toImage(ev);
  if (state.drag >= 0) {
    state.points[state.drag] = p;
    draw();
  } else {
    canvas.style.cursor = handleAt(p) >= 0 && state.points.length === 2 ? "grab" : "crosshair";
  }
});

function endDrag(ev) {
  if (state.drag < 0) return;
  state.drag = -1;
  if (canvas.hasPointerCapture(ev.pointerId)) canvas.releasePointerCapture(ev.pointerId);
  measure(true);
}
canvas.addEventListener("pointerup", endDrag);
canvas.addEventListener("pointercancel", endDrag);

// ---- measuring ----------------------------------------------------------------------------------
async function measure(adjusting) {
  if (state.points.length !== 2 || !state.frame) return;
  const previous = adjusting && state.result ? state.result.id : null;
  const body = { frame_id: state.frame.id, p1: state.points[0], p2: state.points[1], options: { method: state.method } };
  $("hint").textContent = "Measuring…";
  try {
    const res = await api("api/measure", { method: "POST", body });
    state.result = res;
    showResult(res);
    // Adjusting a segment replaces its history entry rather than adding one per drag.
    if (previous !== null) await api(`api/measurements/${previous}`, { method: "DELETE" }).catch(() => {});
    await refreshHistory();
    $("hint").textContent = "Drag a handle to adjust, click elsewhere to start again.";
  } catch (e) {
    state.result = null;
    showResult(null);
    showError(e.message);
    $("hint").textContent = "Click two points to measure.";
  }
  draw();
}

function showError(message) {
  const el = $("error");
  el.textContent = message;
  el.classList.toggle("hidden", !message);
}

function showResult(res) {
  showError("");
  const d = $("distance");
  if (!res) {
    d.textContent = "—";
    d.dataset.metres = "";
    delete d.dataset.id;
    $("uncertainty").innerHTML = "&nbsp;";
    for (const id of ["r-method", "r-fit", "r-samples", "r-basic", "r-time"]) $(id).textContent = "—";
    $("warnings").replaceChildren();
    return;
  }
  d.textContent = fmt(res.distance_m);
  d.dataset.metres = res.distance_m === null ? "" : String(res.distance_m);
  d.dataset.id = String(res.id);
  $("uncertainty").textContent = fmtUncertainty(res.uncertainty_m);
  $("r-method").textContent = res.method;
  $("r-fit").textContent = res.fit;
  $("r-samples").textContent = `${res.n_support} / ${res.n_valid} (of ${res.n_samples})`;
  $("r-basic").textContent = fmt(res.basic_distance_m);
  $("r-time").textContent = `${res.elapsed_ms.toFixed(1)} ms`;
  const warnings = [...res.warnings];
  if (res.gap_detected && !warnings.some((w) => /gap/i.test(w))) warnings.unshift("gap detected between the end points");
  $("warnings").replaceChildren(...warnings.map((w) => Object.assign(document.createElement("li"), { textContent: w })));
}

function clearPoints() {
  state.points = [];
  state.result = null;
  state.drag = -1;
  showResult(null);
  $("hint").textContent = "Click two points to measure. Drag a handle to adjust.";
  draw();
}

// ---- history ------------------------------------------------------------------------------------
async function refreshHistory() {
  let items = [];
  try { items = await api("api/measurements?limit=100"); } catch (e) { return; }
  const list = $("history");
  list.replaceChildren(...items.map(historyItem));
  $("history-empty").classList.toggle("hidden", items.length > 0);
}

function historyItem(m) {
  const li = document.createElement("li");
  li.dataset.id = m.id;
  const img = Object.assign(document.createElement("img"), { src: withToken(`api/measurements/${m.id}/thumb.png`), alt: "" });
  const text = document.createElement("div");
  const when = new Date(m.created * 1000).toLocaleTimeString();
  const unc = m.uncertainty_m === null ? "" : fmtPlusMinus(m.uncertainty_m) + " · ";
  text.innerHTML = `<div class="h-dist"></div><div class="h-meta"></div>`;
  text.firstChild.textContent = fmt(m.distance_m);
  text.lastChild.textContent = `${unc}${m.method} · ${m.fit} · ${when}${m.warnings.length ? " · ⚠ " + m.warnings.length : ""}`;
  text.lastChild.title = m.warnings.join("\n");
  const del = Object.assign(document.createElement("button"), { className: "h-del", title: "Delete", textContent: "×" });
  del.addEventListener("click", async (ev) => {
    ev.stopPropagation();
    await api(`api/measurements/${m.id}`, { method: "DELETE" }).catch((e) => showError(e.message));
    if (state.result && state.result.id === m.id) clearPoints();
    refreshHistory();
  });
  li.addEventListener("click", () => reopen(m.id));
  li.append(img, text, del);
  return li;
}

async function reopen(id) {
  try {
    const { frame, measurement } = await api(`api/measurements/${id}/open`, { method: "POST" });
    state.frozen = true;
    updateFreezeButton();
    state.points = [measurement.p1, measurement.p2];
    state.result = measurement;
    await showFrame(frame);
    showResult(measurement);
    draw();
  } catch (e) {
    showError(e.message);
  }
}

// ---- source status and recording ----------------------------------------------------------------
async function pollSource() {
  const pill = $("source-status");
  const msg = $("stage-msg");
  try {
    const s = await api("api/source");
    const name = s.name || s.spec || "source";
    const size = s.width ? ` · ${s.width}×${s.height}` : "";
    const fps = s.measured_fps ? ` · ${s.measured_fps.toFixed(1)} fps` : s.fps ? ` · ${s.fps} fps` : "";
    let cls = "pill-ok", text = `${name}${size}${fps}`;
    if (s.state === "disconnected" || s.state === "reconnecting") {
      cls = "pill-bad";
      const retry = s.retry_in_s > 0.5 ? ` — retrying in ${Math.ceil(s.retry_in_s)} s` : " — reconnecting…";
      text = `${name}: ${s.state}${retry}`;
      msg.textContent = `Source ${s.state}: ${s.message || "no frames"}${retry}`;
    } else if (s.state === "ended") {
      cls = "pill-wait";
      text = `${name}: ended · last frame kept`;
    } else if (s.state !== "streaming") {
      cls = "pill-wait";
      text = `${name}: ${s.state}…`;
    }
    msg.classList.toggle("hidden", cls !== "pill-bad" || state.frozen);
    pill.className = "pill " + cls;
    pill.textContent = text;
    pill.title = s.message || s.spec;
    setRecording(s.recording);
  } catch (e) {
    pill.className = "pill pill-bad";
    pill.textContent = "service unreachable";
    pill.title = e.message;
  }
}

function setRecording(rec) {
  state.recording = !!(rec && rec.active);
  const b = $("record");
  b.classList.toggle("on", state.recording);
  $("record-label").textContent = state.recording ? `Stop (${rec.frames})` : "Record";
  b.title = rec && rec.path ? `${rec.active ? "Recording to" : "Last recording:"} ${rec.path}${rec.error ? " — " + rec.error : ""}` : "Start/stop recording (r)";
}

async function toggleRecording() {
  try {
    setRecording(await api("api/recordings", { method: "POST", body: { action: state.recording ? "stop" : "start" } }));
  } catch (e) {
    showError(e.message);
  }
}

// ---- controls -----------------------------------------------------------------------------------
function setUnits(u) {
  state.units = u;
  localStorage.setItem("depthruler-units", u);
  $("units").value = u;
  showResult(state.result);
  refreshHistory();
  draw();
}

function setMethod(m) {
  state.method = m;
  localStorage.setItem("depthruler-method", m);
  $("method").value = m;
  if (state.points.length === 2) measure(true);
}

$("units").addEventListener("change", (e) => setUnits(e.target.value));
$("method").addEventListener("change", (e) => setMethod(e.target.value));
$("freeze").addEventListener("click", () => (state.frozen ? goLive() : freeze()));
$("view-color").addEventListener("click", () => setView("color"));
$("view-disparity").addEventListener("click", () => setView("disparity"));
$("clear").addEventListener("click", clearPoints);
$("record").addEventListener("click", toggleRecording);
$("csv").addEventListener("click", (e) => { e.preventDefault(); location.href = withToken("api/measurements.csv"); });

document.addEventListener("keydown", (e) => {
  if (e.target.tagName === "SELECT" || e.target.tagName === "INPUT" || e.ctrlKey || e.metaKey || e.altKey) return;
  const keys = Object.keys(UNITS);
  switch (e.key) {
    case "Escape":
      if (state.drag >= 0 || state.points.length) clearPoints(); else goLive();
      break;
    case "f": state.frozen ? goLive() : freeze(); break;
    case "d": setView(state.view === "color" ? "disparity" : "color"); break;
    case "u": setUnits(keys[(keys.indexOf(state.units) + 1) % keys.length]); break;
    case "m": setMethod(METHODS[(METHODS.indexOf(state.method) + 1) % METHODS.length]); break;
    case "r": toggleRecording(); break;
    default: return;
  }
  e.preventDefault();
});
window.addEventListener("resize", () => { fitCanvas(); draw(); });

$("units").value = state.units in UNITS ? state.units : (state.units = "m");
$("method").value = METHODS.includes(state.method) ? state.method : (state.method = "robust");
fitCanvas();
pollSource();
pollLive();
refreshHistory();
setInterval(pollLive, 250);
setInterval(pollSource, 1000);
