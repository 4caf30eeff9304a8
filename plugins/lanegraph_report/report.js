// lanegraph report: the frame viewer, the node pictures, the side-by-side view and sortable tables.
// Plain JavaScript, no library; every text from the data goes in through textContent.
(function () {
  "use strict";
  const D = JSON.parse(document.getElementById("report-data").textContent);
  const $ = (id) => document.getElementById(id);
  const SVG = "http://www.w3.org/2000/svg";
  const multiSeq = D.sequences.length > 1;

  let tab = "frames";
  let variant = 0; // whose lanes the Frames tab shows
  let visible = []; // indices into D.frames listed in the Frames tab
  let pos = 0; // position in `visible`
  let cmpA = 0, cmpB = Math.min(1, D.variants.length - 1);
  let cmpList = [], cmpDis = new Set(), cmpPos = 0;

  const run = (f, v) => f.r[v] || null;
  const failed = (f, v) => { const r = run(f, v); return !!(r && r.fail); };
  const label = (f) => (multiSeq ? D.sequences[f.s].name + " / " : "") + f.id;

  // ------------------------------------------------------------------ drawing a frame
  function el(name, attrs) {
    const e = document.createElementNS(SVG, name);
    for (const k in attrs) e.setAttribute(k, attrs[k]);
    return e;
  }
  function polyline(pts, cls, tip) {
    const p = el("polyline", { points: pts.map((q) => q[0] + "," + q[1]).join(" "), class: cls });
    if (tip) { const t = el("title", {}); t.textContent = tip; p.appendChild(t); }
    return p;
  }
  function draw(box, f, v) {
    const svg = el("svg", { viewBox: "0 0 " + f.w + " " + f.h, class: "frame", preserveAspectRatio: "xMidYMid meet" });
    if (f.img) {
      svg.appendChild(el("image", { href: f.img, x: 0, y: 0, width: f.w, height: f.h, preserveAspectRatio: "none" }));
    } else {
      const t = el("text", { x: 20, y: 40 });
      t.textContent = "left image not available";
      svg.appendChild(t);
    }
    const r = run(f, v);
    if (f.gt) {
      f.gt.forEach((m, j) => {
        const o = r && r.mo ? r.mo[j] : "plain";
        const tip = "marking " + m.id + (m.kind ? " (" + m.kind + ")" : "") + (m.ego ? ", ego " + m.ego + " boundary" : "") + ": " + o.replace("_", " ");
        svg.appendChild(polyline(m.pts, "gt " + o, tip));
      });
    }
    if (r) {
      r.lanes.forEach((ln, i) => {
        const o = ln.o || "plain";
        let tip = "lane " + i + (ln.side ? " (" + ln.side + ")" : "") + (ln.score !== null ? ", score " + ln.score.toFixed(2) : "");
        if (ln.o) tip += ": " + (ln.o === "matched" ? "matched, mean |dx| " + ln.dx + " px" : "false lane");
        svg.appendChild(polyline(ln.pts, "lane " + o, tip));
      });
    }
    box.replaceChildren(svg);
  }
  function metricLine(box, f, v) {
    const r = run(f, v);
    box.textContent = r ? r.line : "no run of " + D.variants[v] + " on this sequence";
    box.classList.toggle("failed", failed(f, v));
  }

  // ------------------------------------------------------------------ Frames tab
  function frameItem(f, i, cls, onclick) {
    const li = document.createElement("li");
    li.className = "frame " + cls;
    li.dataset.index = String(i);
    li.dataset.frame = f.id;
    li.dataset.seq = D.sequences[f.s].name;
    li.textContent = f.id;
    li.addEventListener("click", onclick);
    return li;
  }
  function fillList(ol, indices, clsOf, onclick) {
    ol.replaceChildren();
    let seq = -1;
    indices.forEach((i, k) => {
      const f = D.frames[i];
      if (multiSeq && f.s !== seq) {
        seq = f.s;
        const h = document.createElement("li");
        h.className = "seq-head";
        h.textContent = D.sequences[seq].name;
        ol.appendChild(h);
      }
      ol.appendChild(frameItem(f, i, clsOf(f, i), () => onclick(k)));
    });
  }
  function buildList() {
    const current = visible.length ? visible[pos] : -1;
    const only = $("failed-only").checked;
    visible = [];
    D.frames.forEach((f, i) => { if (!only || failed(f, variant)) visible.push(i); });
    fillList($("frame-list"), visible, (f) => {
      const r = run(f, variant);
      return r && r.fail ? "failed" : r && r.ok ? "ok" : "";
    }, show);
    const nFailed = D.frames.filter((f) => failed(f, variant)).length;
    $("list-count").textContent = visible.length + " of " + D.frames.length + " frame(s) listed; " + nFailed + " failed";
    $("frame-slider").max = String(Math.max(visible.length - 1, 0));
    const k = visible.indexOf(current);
    show(k >= 0 ? k : 0);
  }
  function show(k) {
    const view = $("frame-view");
    if (!visible.length) {
      view.replaceChildren();
      $("frame-id").textContent = "no frame listed";
      $("metric-line").textContent = "";
      return;
    }
    pos = Math.max(0, Math.min(k, visible.length - 1));
    const f = D.frames[visible[pos]];
    draw(view, f, variant);
    $("frame-id").textContent = label(f) + "  (" + (pos + 1) + "/" + visible.length + ")";
    $("frame-id").dataset.frame = f.id;
    metricLine($("metric-line"), f, variant);
    $("frame-slider").value = String(pos);
    mark($("frame-list"), visible[pos]);
    showNodes(f);
  }
  function mark(ol, index) {
    for (const li of ol.querySelectorAll("li.current")) li.classList.remove("current");
    const li = ol.querySelector('li.frame[data-index="' + index + '"]');
    if (li) { li.classList.add("current"); li.scrollIntoView({ block: "nearest" }); }
  }

  // ------------------------------------------------------------------ Nodes tab
  const debugFrames = D.frames.map((f, i) => (f.dbg ? i : -1)).filter((i) => i >= 0);
  function showNodes(f) {
    const box = $("node-pictures");
    box.replaceChildren();
    if (!debugFrames.length) {
      $("node-frame").textContent = "No frame of this run was recorded with --debug-dir (lanegraph run ... --debug-dir DIR --debug-frames 0,20).";
      return;
    }
    if (!f.dbg) {
      $("node-frame").textContent = "Frame " + label(f) + " has no node pictures; frames that have them:";
      return;
    }
    $("node-frame").textContent = "Every node's picture of frame " + label(f) + ", in graph order:";
    for (const p of f.dbg) {
      const fig = document.createElement("figure");
      const link = document.createElement("a"); // the picture alone, at its size in the report
      link.href = p.src;
      link.target = "_blank";
      const img = document.createElement("img");
      img.src = p.src;
      img.alt = p.cap;
      link.appendChild(img);
      const cap = document.createElement("figcaption");
      cap.textContent = p.cap;
      fig.append(link, cap);
      box.appendChild(fig);
    }
  }
  function buildJump() {
    const box = $("node-jump");
    for (const i of debugFrames) {
      const b = document.createElement("button");
      b.textContent = label(D.frames[i]);
      b.addEventListener("click", () => {
        let k = visible.indexOf(i);
        if (k < 0) { $("failed-only").checked = false; buildList(); k = visible.indexOf(i); }
        show(k);
      });
      box.appendChild(b);
    }
  }

  // ------------------------------------------------------------------ side by side
  function outcomes(r) { return r.lanes.map((l) => l.o || "").sort().join(","); }
  function disagree(f) {
    const a = run(f, cmpA), b = run(f, cmpB);
    if (!a || !b) return !!a !== !!b;
    if (a.fail !== b.fail || a.ok !== b.ok) return true;
    return a.lanes.length !== b.lanes.length || outcomes(a) !== outcomes(b);
  }
  function buildCompare() {
    const dis = [], same = [];
    D.frames.forEach((f, i) => (disagree(f) ? dis : same).push(i));
    cmpList = dis.concat(same);
    cmpDis = new Set(dis);
    fillList($("cmp-list"), cmpList, (f, i) => (cmpDis.has(i) ? "disagree" : ""), cmpShow);
    $("cmp-count").textContent = dis.length + " frame(s) where " + D.variants[cmpA] + " and " + D.variants[cmpB] + " disagree, listed first";
    $("cmp-name-a").textContent = "A: " + D.variants[cmpA];
    $("cmp-name-b").textContent = "B: " + D.variants[cmpB];
    cmpShow(0);
  }
  function cmpShow(k) {
    if (!cmpList.length) return;
    cmpPos = Math.max(0, Math.min(k, cmpList.length - 1));
    const f = D.frames[cmpList[cmpPos]];
    draw($("cmp-view-a"), f, cmpA);
    draw($("cmp-view-b"), f, cmpB);
    metricLine($("cmp-line-a"), f, cmpA);
    metricLine($("cmp-line-b"), f, cmpB);
    $("cmp-frame-id").textContent = label(f) + (cmpDis.has(cmpList[cmpPos]) ? "  (they disagree)" : "  (same outcome)");
    $("cmp-frame-id").dataset.frame = f.id;
    mark($("cmp-list"), cmpList[cmpPos]);
  }
  function fillSelect(sel, value) {
    D.variants.forEach((name, i) => {
      const o = document.createElement("option");
      o.value = String(i);
      o.textContent = name;
      sel.appendChild(o);
    });
    sel.value = String(value);
  }

  // ------------------------------------------------------------------ sortable tables
  function cellValue(row, c) {
    const td = row.cells[c];
    if (!td) return "";
    return td.dataset.v !== undefined ? Number(td.dataset.v) : td.textContent;
  }
  function sortTable(table, c, th) {
    const asc = th.dataset.dir !== "asc";
    for (const h of table.tHead.rows[0].cells) delete h.dataset.dir;
    th.dataset.dir = asc ? "asc" : "desc";
    const rows = Array.from(table.tBodies[0].rows);
    rows.sort((r1, r2) => {
      const a = cellValue(r1, c), b = cellValue(r2, c);
      const na = typeof a === "number", nb = typeof b === "number";
      let d;
      if (na && nb) d = a - b;
      else if (na !== nb) d = na ? -1 : 1; // numbers before n/a
      else d = String(a).localeCompare(String(b));
      return asc ? d : -d;
    });
    table.tBodies[0].append(...rows);
  }

  // ------------------------------------------------------------------ wiring
  function setTab(name) {
    tab = name;
    for (const b of document.querySelectorAll("#tabs button")) b.classList.toggle("active", b.dataset.tab === name);
    for (const s of document.querySelectorAll("section.tab")) s.hidden = s.id !== name;
  }
  function step(d) {
    if (tab === "compare") cmpShow(cmpPos + d);
    else show(pos + d);
  }
  for (const b of document.querySelectorAll("#tabs button")) b.addEventListener("click", () => setTab(b.dataset.tab));
  document.addEventListener("keydown", (e) => {
    const t = e.target;
    if (t && (t.tagName === "SELECT" || t.tagName === "TEXTAREA" || (t.tagName === "INPUT" && t.type !== "checkbox"))) return;
    if (e.key === "ArrowRight") { step(1); e.preventDefault(); }
    else if (e.key === "ArrowLeft") { step(-1); e.preventDefault(); }
  });
  $("prev").addEventListener("click", () => step(-1));
  $("next").addEventListener("click", () => step(1));
  $("frame-slider").addEventListener("input", (e) => show(Number(e.target.value)));
  $("failed-only").addEventListener("change", buildList);
  if (D.variants.length > 1) {
    $("variant-box").hidden = false;
    fillSelect($("variant"), 0);
    $("variant").addEventListener("change", (e) => { variant = Number(e.target.value); buildList(); });
    $("tab-compare").hidden = false;
    fillSelect($("cmp-a"), cmpA);
    fillSelect($("cmp-b"), cmpB);
    $("cmp-a").addEventListener("change", (e) => { cmpA = Number(e.target.value); buildCompare(); });
    $("cmp-b").addEventListener("change", (e) => { cmpB = Number(e.target.value); buildCompare(); });
    buildCompare();
  }
  for (const table of document.querySelectorAll("table.sortable")) {
    Array.from(table.tHead.rows[0].cells).forEach((th, c) => th.addEventListener("click", () => sortTable(table, c, th)));
  }
  buildJump();
  buildList();
  document.body.dataset.ready = "1";
})();
