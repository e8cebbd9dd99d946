"use strict";
// The accuracy check on the page: a card in the side panel with a "Check accuracy" button that runs the
// board check (POST /api/checks) on the frozen frame, shows its picture, figures and findings, and lists
// the check history (GET /api/checks). It talks to app.js only through the page: the canvas's
// data-frame-id / data-frozen and the Freeze button, so either file can change on its own.
(function () {
  const $ = (id) => document.getElementById(id);
  const token = () => new URLSearchParams(location.search).get("token") || sessionStorage.getItem("depthruler-token") || "";
  const withToken = (url) => (token() ? url + (url.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(token()) : url);
  const STATUS_WORD = { ok: "good", check: "check", poor: "poor" };
  const verdictClass = (status) => `verdict v-${status === "ok" ? "good" : status === "check" ? "check" : "unreliable"}`;

  async function api(path, body) {
    const headers = {};
    if (token()) headers.Authorization = "Bearer " + token();
    const init = { method: body === undefined ? "GET" : "POST", headers };
    if (body !== undefined) {
      headers["Content-Type"] = "application/json";
      init.body = JSON.stringify(body);
    }
    const res = await fetch(path, init);
    const data = (res.headers.get("content-type") || "").includes("json") ? await res.json() : await res.text();
    if (!res.ok) throw new Error(typeof data === "object" && data.detail ? data.detail : `${res.status} ${res.statusText}`);
    return data;
  }

  function el(tag, attrs = {}, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) {
      if (k === "class") e.className = v;
      else if (k === "text") e.textContent = v;
      else e.setAttribute(k, v);
    }
    for (const c of children) e.append(c);
    return e;
  }

  function buildCard() {
    const field = (label, input) => el("label", { class: "check-field" }, el("span", { text: label }), input);
    const card = el("section", { class: "card check", id: "check-card" },
      el("div", { class: "card-title row", text: "Accuracy check" }),
      el("div", { class: "muted check-help", text: "Hold a printed ChArUco board in view, then check: its known lengths are measured as if clicked." }),
      el("details", { class: "details", id: "check-board" },
        el("summary", { text: "Board (empty: the source's, or 11x8 × 30 mm)" }),
        el("div", { class: "check-fields" },
          field("Squares", el("input", { id: "check-squares", placeholder: "7x5", size: "5" })),
          field("Square mm", el("input", { id: "check-square-mm", type: "number", step: "0.1", min: "0" })),
          field("Marker mm", el("input", { id: "check-marker-mm", type: "number", step: "0.1", min: "0" })),
          field("Dictionary", el("input", { id: "check-dictionary", placeholder: "DICT_5X5_100", size: "12" })))),
      el("div", { class: "row check-actions" },
        el("button", { id: "check-run", class: "btn small", title: "Freeze and check the board in view (k)", text: "Check accuracy" }),
        el("select", { id: "check-frames", title: "Frames to check: the frozen one and those just before it" },
          ...[1, 3, 5].map((n) => el("option", { value: String(n), text: `${n} frame${n > 1 ? "s" : ""}` }))),
        el("span", { id: "check-state", class: "muted" })),
      el("div", { id: "check-error", class: "error hidden" }),
      el("div", { id: "check-result", class: "check-result hidden" },
        el("div", { class: "row" }, el("span", { id: "check-status", class: "verdict" }), el("span", { id: "check-figures", class: "check-figures" })),
        el("div", { id: "check-frames-note", class: "check-frames-note hidden" }),
        el("ul", { id: "check-findings", class: "check-findings" }),
        el("a", { id: "check-link", target: "_blank", rel: "noopener" }, el("img", { id: "check-img", class: "check-img", alt: "The board with its pairs coloured by error" }))),
      el("div", { class: "card-title", text: "Check history" }),
      el("ul", { id: "check-history", class: "history-list check-history" }),
      el("div", { id: "check-history-empty", class: "muted", text: "No checks yet." }));
    const panel = document.querySelector(".panel") || document.body;
    panel.append(card);
  }

  function boardBody() {
    const squares = $("check-squares").value.trim();
    const sq = $("check-square-mm").value, mk = $("check-marker-mm").value, dict = $("check-dictionary").value.trim();
    if (!squares && !sq && !mk && !dict) return null; // the source's own board
    const board = {};
    if (squares) {
      const m = /^(\d+)\s*[x×]\s*(\d+)$/i.exec(squares);
      if (!m) throw new Error(`squares "${squares}" is not COLSxROWS, e.g. 7x5`);
      board.squares_x = Number(m[1]);
      board.squares_y = Number(m[2]);
    }
    if (sq) board.square_mm = Number(sq);
    if (mk) board.marker_mm = Number(mk);
    if (dict) board.dictionary = dict;
    return board;
  }

  async function frozenFrameId() {
    const canvas = $("canvas");
    if (canvas.dataset.frozen !== "1") {
      $("freeze").click(); // app.js freezes the frame on screen, as the f key does
      const until = performance.now() + 10000;
      while (canvas.dataset.frozen !== "1") {
        if (performance.now() > until) throw new Error("the frame did not freeze; press Freeze, then check");
        await new Promise((r) => setTimeout(r, 50));
      }
    }
    const id = Number(canvas.dataset.frameId);
    if (!Number.isInteger(id)) throw new Error("no frame on screen yet");
    return id;
  }

  const pct = (x, digits = 2) => (x === null || x === undefined ? "–" : `${x >= 0 ? "+" : ""}${x.toFixed(digits)} %`);

  function show(rec) {
    const f = rec.figures || {};
    const card = $("check-card");
    card.dataset.checkId = rec.id || "";
    card.dataset.status = rec.status || "";
    $("check-result").classList.remove("hidden");
    const st = $("check-status");
    st.textContent = STATUS_WORD[rec.status] || rec.status;
    st.className = verdictClass(rec.status);
    const dist = f.distance_m === null || f.distance_m === undefined ? "" : ` at ${f.distance_m.toFixed(2)} m`;
    $("check-figures").textContent = `${f.pairs} pairs on ${f.frames_with_board}/${f.frames} frames${dist}: bias ${pct(f.bias_pct)}, ` +
      `spread ${f.spread_pct === undefined ? "–" : f.spread_pct.toFixed(2)} %, truth inside the 95 % interval ${Math.round(100 * (f.interval_coverage || 0))} %`;
    $("check-figures").dataset.bias = String(f.bias_pct);
    $("check-figures").dataset.pairs = String(f.pairs);
    // fewer frames than asked for (the ring held no more before the frozen one): said, not hidden
    $("check-frames-note").textContent = rec.frames_note || "";
    $("check-frames-note").classList.toggle("hidden", !rec.frames_note);
    const list = $("check-findings");
    list.replaceChildren(...(rec.findings || []).map((x) => el("li", { class: `finding finding-${x.severity}` },
      el("b", { text: `${x.severity}: ` }), x.measured,
      ...(x.action ? [el("div", { class: "finding-do", text: `do: ${x.action}` })] : []))));
    if (!list.children.length) list.append(el("li", { class: "finding finding-info", text: "nothing to act on" }));
    const img = $("check-img");
    if (rec.png_url) {
      img.src = withToken(rec.png_url);
      $("check-link").href = img.src;
      img.classList.remove("hidden");
    } else {
      img.removeAttribute("src");
      img.classList.add("hidden"); // a check from the command line keeps its picture in its --out folder
    }
  }

  async function refreshHistory() {
    const data = await api("api/checks?limit=20");
    const items = data.checks || [];
    $("check-history-empty").classList.toggle("hidden", items.length > 0);
    $("check-history").replaceChildren(...items.map((rec) => {
      const f = rec.figures || {};
      const when = (rec.time || "").replace("T", " ").replace(/\+00:00$/, " UTC");
      const li = el("li", { class: "check-item", title: rec.source || "" },
        el("span", { class: verdictClass(rec.status), text: STATUS_WORD[rec.status] || rec.status }),
        ` ${when} · bias ${pct(f.bias_pct)} · ${f.pairs} pairs${rec.frames_note ? ` · ${rec.frame_ids.length} of ${rec.frames_requested} frames` : ""}` +
        `${rec.png_url ? "" : " · cli"}`);
      li.dataset.checkId = rec.id || "";
      li.addEventListener("click", () => show(rec));
      return li;
    }));
  }

  async function run() {
    const button = $("check-run");
    $("check-error").classList.add("hidden");
    button.disabled = true;
    $("check-state").textContent = "checking…";
    try {
      const board = boardBody();
      const body = { frame_id: await frozenFrameId(), frames: Number($("check-frames").value) };
      if (board) body.board = board;
      show(await api("api/checks", body));
      await refreshHistory();
      $("check-state").textContent = "";
    } catch (err) {
      $("check-state").textContent = "";
      $("check-error").textContent = err.message;
      $("check-error").classList.remove("hidden");
    } finally {
      button.disabled = false;
    }
  }

  buildCard();
  $("check-run").addEventListener("click", run);
  document.addEventListener("keydown", (ev) => {
    if (ev.key === "k" && !ev.ctrlKey && !ev.metaKey && !ev.altKey && !["INPUT", "SELECT", "TEXTAREA"].includes(document.activeElement.tagName)) run();
  });
  refreshHistory().catch(() => {}); // the history is a courtesy: the page works without it
})();
