// goniofrost monitor page: follows /api/events (server-sent events) and draws with inline SVG.
// Everything the page shows comes from the state JSON (goniofrost/monitor/status.py); this file
// only lays it out. Text is always set with textContent, never parsed as HTML.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const $ = (id) => document.getElementById(id);
const page = { state: null, clockOffset: 0, planKey: null, planDots: [], snrDots: [], expDots: [],
               frameWanted: null, frameShown: null, previewWanted: null, previewShown: null,
               timers: {}, renderMs: [] };

function svgEl(name, attrs, parent) {
  const el = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs || {})) el.setAttribute(k, v);
  if (parent) parent.appendChild(el);
  return el;
}

function setText(id, text) {
  const el = $(id);
  if (el.textContent !== text) el.textContent = text;
}

function agoText(seconds) {
  const s = Math.max(0, Math.round(seconds));
  if (s < 60) return `${s} s ago`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, "0")} s ago`;
  return `${Math.floor(s / 3600)} h ${String(Math.floor((s % 3600) / 60)).padStart(2, "0")} min ago`;
}

// ----- overview, fault, files -------------------------------------------------------------
function renderOverview(st) {
  setText("session", st.session + (st.rig ? `  ·  rig ${st.rig}` : "") + (st.material ? `  ·  ${st.material}` : ""));
  setText("label", st.label_text || "");
  const badge = $("state");
  badge.dataset.state = st.state;
  setText("state", st.state);
  setText("count", st.count_text);
  $("progress").max = Math.max(st.total, 1);
  $("progress").value = st.done;
  setText("hint", st.hint || "");
  document.title = `${st.state} · ${st.count_text} · goniofrost monitor`;
  renderLastEvent();
}

function durationText(seconds) {
  return agoText(seconds).replace(/ ago$/, "");
}

// Every second: the last event's age and the ETA counting down from the last journaled sample.
function renderLastEvent() {
  const st = page.state;
  if (!st) return;
  const now = Date.now() / 1000 - page.clockOffset;
  if (st.eta_s == null) setText("eta", st.eta_text || "");
  else {
    const left = st.eta_s - (now - st.eta_from_utc);
    setText("eta", left < 1 ? "less than 1 s left" : `about ${durationText(left)} left`);
  }
  const e = st.last_event;
  if (e) setText("last-event", `${e.kind}${e.axis ? " (" + e.axis + ")" : ""}: ${e.message} · ${agoText(now - e.t_utc)}`);
}

function renderFault(st) {
  const box = $("fault");
  const stopped = st.stop && (st.state === "faulted" || st.state === "interrupted");
  if (!stopped && !st.ended_message) { box.hidden = true; return; }
  box.hidden = false;
  setText("fault-title", st.ended_message ? "The capture ended with an error" :
          st.stop.status === st.names.run_status.STOPPED_BY_OPERATOR ? "Interrupted" : "Stopped on a fault");
  setText("fault-message", st.ended_message || st.stop.message);
  setText("fault-detail", st.stop && !st.ended_message && st.stop.detail && !st.stop.message.includes(st.stop.detail)
          ? `device: ${st.stop.detail}` : "");
}

function renderFiles(st) {
  const summary = $("summary-text");
  summary.hidden = !st.summary;
  setText("summary-text", st.summary || "");
  const list = $("file-list");
  const key = st.files.join("\n");
  if (list.dataset.key === key) return;
  list.dataset.key = key;
  list.replaceChildren(...st.files.map((name) => {
    const li = document.createElement("li");
    const a = document.createElement("a");
    a.href = "files/" + encodeURIComponent(name);
    a.textContent = name;
    li.appendChild(a);
    return li;
  }));
}

// ----- plan chart: every sample at (theta_i, theta_o), coloured by status --------------------
const PLAN = { x0: 40, y0: 265, w: 260, h: 250, max: 90 };

function planXY(ti, to) {
  return [PLAN.x0 + (ti / PLAN.max) * PLAN.w, PLAN.y0 - (to / PLAN.max) * PLAN.h];
}

function buildPlanChart(st) {
  const svg = $("plan-chart");
  svg.replaceChildren();
  for (const t of [0, 30, 60, 90]) {
    const [x] = planXY(t, 0), [, y] = planXY(0, t);
    svgEl("line", { class: "grid-line", x1: x, y1: PLAN.y0, x2: x, y2: PLAN.y0 - PLAN.h }, svg);
    svgEl("line", { class: "grid-line", x1: PLAN.x0, y1: y, x2: PLAN.x0 + PLAN.w, y2: y }, svg);
    svgEl("text", { x: x - 5, y: PLAN.y0 + 13 }, svg).textContent = t;
    svgEl("text", { x: PLAN.x0 - 22, y: y + 3 }, svg).textContent = t;
  }
  svgEl("path", { class: "axis", d: `M${PLAN.x0},${PLAN.y0 - PLAN.h} V${PLAN.y0} H${PLAN.x0 + PLAN.w}` }, svg);
  svgEl("text", { x: PLAN.x0 + PLAN.w / 2 - 40, y: PLAN.y0 + 28 }, svg).textContent = "θi (deg, light)";
  const label = svgEl("text", { x: 10, y: PLAN.y0 - PLAN.h / 2 + 40, transform: `rotate(-90 10 ${PLAN.y0 - PLAN.h / 2 + 40})` }, svg);
  label.textContent = "θo (deg, view)";
  const layer = svgEl("g", { id: "plan-dots" }, svg);
  const r = st.total > 200 ? 2.5 : 4.5;
  const s = st.samples;
  page.planDots = s.status.map((status, i) => {
    const [x, y] = planXY(s.theta_i_deg[i] ?? 0, s.theta_o_deg[i] ?? 0);
    const dot = svgEl("circle", { cx: x.toFixed(1), cy: y.toFixed(1), r }, layer);
    svgEl("title", {}, dot);
    dot.dataset.index = i;
    return dot;
  });
}

function renderPlanChart(st) {
  if (page.planKey !== st.plan_key || page.planDots.length !== st.total) {
    buildPlanChart(st);
    buildSeries(st);
    page.planKey = st.plan_key;
  }
  const s = st.samples;
  page.planDots.forEach((dot, i) => {
    const status = s.status[i];
    if (dot.dataset.status === status && dot.dataset.snr === String(s.snr[i])) return;
    dot.dataset.status = status;
    dot.dataset.snr = String(s.snr[i]);
    dot.setAttribute("class", "s-" + status);
    const snr = s.snr[i] == null ? "" : `, SNR ${s.snr[i].toFixed(0)}`;
    dot.firstChild.textContent = `sample ${i}: θi ${(s.theta_i_deg[i] ?? NaN).toFixed(1)}°, θo ${(s.theta_o_deg[i] ?? NaN).toFixed(1)}°, ${status}${snr}`;
    if (status === "next" || status === "failed") dot.parentNode.appendChild(dot); // on top
  });
}

// ----- per-sample series: SNR and exposure on log axes against the capture order -------------
const SERIES = { x0: 44, y0: 125, w: 266, h: 105 };

function logAxis(svg, lo, hi, title) {
  svg.replaceChildren();
  for (let e = Math.ceil(Math.log10(lo)); e <= Math.floor(Math.log10(hi)); e++) {
    const y = SERIES.y0 - ((e - Math.log10(lo)) / (Math.log10(hi) - Math.log10(lo))) * SERIES.h;
    svgEl("line", { class: "grid-line", x1: SERIES.x0, y1: y, x2: SERIES.x0 + SERIES.w, y2: y }, svg);
    svgEl("text", { x: 2, y: y + 3 }, svg).textContent = e >= 0 ? String(10 ** e) : `1e${e}`;
  }
  svgEl("path", { class: "axis", d: `M${SERIES.x0},${SERIES.y0 - SERIES.h} V${SERIES.y0} H${SERIES.x0 + SERIES.w}` }, svg);
  svgEl("text", { x: SERIES.x0 + 4, y: 12 }, svg).textContent = title;
  svgEl("text", { x: SERIES.x0 + SERIES.w - 110, y: SERIES.y0 + 16 }, svg).textContent = "sample (capture order)";
  return svgEl("g", {}, svg);
}

function buildSeries(st) {
  const n = Math.max(st.total, 1);
  const make = (svg, lo, hi, title, cls) => {
    const layer = logAxis(svg, lo, hi, title);
    const r = st.total > 200 ? 1.6 : 3;
    return st.samples.status.map((_, i) => {
      const dot = svgEl("circle", { class: cls, cx: (SERIES.x0 + ((i + 0.5) / n) * SERIES.w).toFixed(1), cy: -10, r }, layer);
      dot.style.display = "none";
      return dot;
    });
  };
  page.snrDots = make($("snr-chart"), 1, 1e4, "SNR (min over R, G, B)", "pt-snr");
  page.expDots = make($("exposure-chart"), 1e-5, 10, "exposure (s, sum of the bracket)", "pt-exposure");
  page.snrDots.range = [1, 1e4];
  page.expDots.range = [1e-5, 10];
}

function placeSeries(dots, values, flags) {
  const [lo, hi] = dots.range;
  dots.forEach((dot, i) => {
    const v = values[i];
    const key = v == null ? "" : String(v);
    if (dot.dataset.v === key) return;
    dot.dataset.v = key;
    if (v == null || !(v > 0)) { dot.style.display = "none"; return; }
    const t = (Math.log10(Math.min(Math.max(v, lo), hi)) - Math.log10(lo)) / (Math.log10(hi) - Math.log10(lo));
    dot.setAttribute("cy", (SERIES.y0 - t * SERIES.h).toFixed(1));
    dot.style.display = "";
    if (flags && flags[i]) dot.classList.add("flagged");
  });
}

// ----- rig poses -----------------------------------------------------------------------------
function drawView(svg, view, side) {
  svg.replaceChildren();
  const pt = ([u, v]) => [u, -v];
  if (side) svgEl("line", { class: "horizon", x1: -1.2, y1: 0, x2: 1.2, y2: 0 }, svg);
  else svgEl("circle", { class: "reach", cx: 0, cy: 0, r: 1 }, svg);
  const [cx, cy] = pt(view.camera);
  svgEl("line", { class: "arm", x1: 0, y1: 0, x2: cx, y2: cy }, svg);
  svgEl("circle", { class: "camera", cx, cy, r: 0.08 }, svg);
  const [lx, ly] = pt(view.lamp);
  svgEl("circle", { class: "lamp", cx: lx, cy: ly, r: 0.1 }, svg);
  svgEl("polygon", { class: "plate", points: view.plate.map((p) => pt(p).join(",")).join(" ") }, svg);
  const [nx, ny] = pt(view.normal);
  svgEl("line", { class: "normal", x1: 0, y1: 0, x2: nx, y2: ny }, svg);
  svgEl("circle", { cx: nx, cy: ny, r: 0.03, fill: "#2a6fb0" }, svg);
  svgEl("text", { x: -1.2, y: -1.08 }, svg).textContent = side ? "side" : "above";
}

function renderPose(id, pose) {
  const fig = $(id);
  const key = JSON.stringify(pose);
  if (fig.dataset.key === key) return;
  fig.dataset.key = key;
  fig.hidden = !pose;
  fig.querySelector(".pose-label").textContent = pose ? pose.label : "none";
  const top = fig.querySelector(".pose-top"), side = fig.querySelector(".pose-side"), table = fig.querySelector(".joints");
  if (!pose) { top.replaceChildren(); side.replaceChildren(); table.replaceChildren(); return; }
  drawView(top, pose.top, false);
  drawView(side, pose.side, true);
  const rows = pose.joints.map(([name, role, deg]) => {
    const tr = document.createElement("tr");
    const a = document.createElement("td"); a.textContent = name;
    const b = document.createElement("td"); b.className = "num"; b.textContent = `${deg.toFixed(2)}°`;
    tr.append(a, b);
    return tr;
  });
  if (pose.theta_i_deg != null) {
    const tr = document.createElement("tr");
    const a = document.createElement("td"); a.textContent = "θi / θo";
    const b = document.createElement("td"); b.className = "num";
    b.textContent = `${pose.theta_i_deg.toFixed(1)}° / ${pose.theta_o_deg.toFixed(1)}°`;
    tr.append(a, b);
    rows.push(tr);
  }
  table.replaceChildren(...rows);
}

// ----- pictures: fetched when what they show changes; the server may hand an older one --------
async function fetchPicture(kind, url, wanted, img, caption, describe) {
  if (page[kind + "Busy"]) return;
  page[kind + "Busy"] = true;
  try {
    const answer = await fetch(url, { cache: "no-store" });
    const shows = Number(answer.headers.get("X-Shows"));
    const retry = Number(answer.headers.get("X-Retry-After-Ms") || 0);
    if (answer.ok) {
      const blob = await answer.blob();
      const old = img.src;
      img.src = URL.createObjectURL(blob);
      img.hidden = false;
      if (old.startsWith("blob:")) URL.revokeObjectURL(old);
      caption.textContent = describe(shows, JSON.parse(answer.headers.get("X-Info") || "{}"));
      img.dataset.shows = String(shows);
    } else {
      caption.textContent = await answer.text();
    }
    page[kind + "Shown"] = shows;
    if (shows !== wanted) {  // an older picture: ask again when the server allows a new one
      clearTimeout(page.timers[kind]);
      page.timers[kind] = setTimeout(() => updatePictures(true), Math.max(retry, 200));
    }
  } catch (err) {  // the server is gone (the capture ended): keep the last picture and its caption
  } finally {
    page[kind + "Busy"] = false;
  }
}

function updatePictures(again) {
  const st = page.state;
  if (!st) return;
  if (st.latest && (again || st.latest.plan_index !== page.frameShown)) {
    const k = st.latest.plan_index;
    fetchPicture("frame", `api/frame.png?sample=${k}`, k, $("frame-img"), $("frame-caption"), (shows, info) =>
      `sample ${shows}: ${info.file || ""}${info.exposure_s ? `, exposure ${info.exposure_s} s` : ""}` +
      `, SNR ${page.state.samples.snr[shows]?.toFixed(0) ?? "–"}, region of interest ${info.roi_pixels} px (green)`);
  }
  if (st.done > 0 && (again || st.done !== page.previewShown)) {
    fetchPicture("preview", `api/preview.png?done=${st.done}`, st.done, $("preview-img"), $("preview-caption"),
      (shows) => `from ${shows} of ${st.total} samples; lit from the front, the side and the back`);
  }
}

// The stopping rule's latest assessment, worded from its numbers (never from a journaled sentence);
// its decision is compared with the values the server names (``names.decision``: status.ENUMS).
function assessmentText(a, decision) {
  const pct = `${+(100 * a.confidence).toPrecision(3)} %`;
  const error = a.scope === "scene" ? "error in the scene's use" : "error";  // a plan made for a scene
  const median = `median estimate ${a.predicted_error.toPrecision(3)}`;
  if (a.out_of_model.length) {
    const unlike = a.out_of_model.includes("design") ? "the design is unlike every design the calibration was fitted on"
      : "unlike every training material";
    return `after ${a.samples} samples: ${unlike} (an extrapolation): ` +
      (a.decision === decision.CONTINUE ? "measuring on" : `${a.decision}, target ${a.target} not reached`);
  }
  // the words of the error figure every output states (frost.confidence.figure)
  if (a.decision === decision.TARGET_REACHED) {
    return `${error} <= ${a.bound.toPrecision(3)} with ${pct} confidence (${median}), within the target ${a.target}`;
  }
  const bound = a.bound == null ? "no bound" : `${error} <= ${a.bound.toPrecision(3)} with ${pct} confidence`;
  return `after ${a.samples} samples: ${bound}, target ${a.target} ` +
    (a.decision === decision.CONTINUE ? "not reached yet" : `not reached (${a.decision})`) + ` (${median})`;
}

function renderAssessment(a, names) {
  const el = $("assessment");
  el.hidden = a == null;
  if (a != null) setText("assessment", assessmentText(a, names.decision));
}

function renderPredicted(st) {
  renderAssessment(st.assessment, st.names);
  const el = $("predicted-error");  // the one error figure every output states (report.json's, or the last batch's)
  el.hidden = st.error_figure == null;
  if (st.error_figure != null) setText("predicted-error", `reconstruction (log-relative MSE): ${st.error_figure}`);
}

// ----- the stream -----------------------------------------------------------------------------
function render(st) {
  if (!st.state) return;  // the server could not read the session yet
  page.state = st;
  page.clockOffset = Date.now() / 1000 - st.server_time;
  renderOverview(st);
  renderFault(st);
  renderPlanChart(st);
  placeSeries(page.snrDots, st.samples.snr, st.samples.flags);
  placeSeries(page.expDots, st.samples.exposure_s);
  renderPose("pose-current", st.poses.current);
  renderPose("pose-next", st.poses.next);
  renderPredicted(st);
  renderFiles(st);
  updatePictures(false);
  document.body.dataset.version = String((Number(document.body.dataset.version) || 0) + 1);
}

function connect() {
  const source = new EventSource("api/events");
  source.addEventListener("state", (event) => {
    const t0 = performance.now();
    render(JSON.parse(event.data));
    page.renderMs.push(performance.now() - t0);  // read by benchmarks/monitor.py
    if (page.renderMs.length > 10000) page.renderMs.splice(0, 5000);
    $("connection").textContent = "live";
    $("connection").classList.remove("lost");
  });
  source.onerror = () => {
    const ended = page.state && ["finished", "nothing measured", "faulted", "interrupted", "failed", "stopped"].includes(page.state.state);
    $("connection").textContent = ended
      ? "the monitor stopped serving (the capture process ended); review with: goniofrost monitor " + page.state.session
      : "connection lost; retrying…";
    $("connection").classList.add("lost");
  };
}

window.goniofrostMonitor = page;  // for the benchmark's timing of renders
setInterval(renderLastEvent, 1000);
connect();
