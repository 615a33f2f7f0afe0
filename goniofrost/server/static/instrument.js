// goniofrost serve's page: the instrument's state from /api/events (server-sent events) and
// /api/status, its queue from /api/queue, and, when the page holds the server's token, the controls.
// The token comes as ?token=T (the address the server prints): it is kept in this tab's
// sessionStorage, taken out of the address bar, and sent only as "Authorization: Bearer T".
// Text is always set with textContent, never parsed as HTML.
"use strict";

const $ = (id) => document.getElementById(id);
const TOKEN_KEY = "goniofrost-serve-token";
const POLL_MS = 5000;          // status polling beside the event stream (a stream that went quiet)
const ui = { token: takeToken(), rig: null, status: null, lastSeq: -1, source: null };

function takeToken() {
  const url = new URL(window.location.href);
  const given = url.searchParams.get("token");
  if (given) {
    sessionStorage.setItem(TOKEN_KEY, given);
    url.searchParams.delete("token");
    history.replaceState(null, "", url.pathname + url.search + url.hash);
  }
  return sessionStorage.getItem(TOKEN_KEY);
}

function el(tag, text, attrs) {
  const node = document.createElement(tag);
  if (text != null) node.textContent = text;
  for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, v);
  return node;
}

// ----- control requests: the server's own error text on a refusal --------------------------------
async function control(method, path, body, errorBox) {
  errorBox.textContent = "";
  delete errorBox.dataset.field;
  const operator = $("operator").value.trim();
  const answer = await fetch(path, {
    method, cache: "no-store",
    headers: { "Authorization": `Bearer ${ui.token}`, "Content-Type": "application/json" },
    body: JSON.stringify({ ...(operator ? { operator } : {}), ...(body || {}) }),
  }).catch((err) => ({ ok: false, status: 0, json: async () => ({ error: `no answer from the server (${err})` }) }));
  if (answer.ok) return answer;
  const refusal = await answer.json().catch(() => ({ error: `HTTP ${answer.status}` }));
  errorBox.textContent = refusal.error || `HTTP ${answer.status}`;
  if (refusal.field) errorBox.dataset.field = refusal.field;
  return null;
}

// ----- state, pose and lamp -------------------------------------------------------------------------
function showStatus(st) {
  ui.status = st;
  const badge = $("state");
  badge.dataset.state = st.state;
  badge.textContent = st.state;
  $("reason").textContent = st.reason || "";
  $("held").hidden = !(st.held && st.state === "idle");
  $("current").textContent = st.current ? `running queue entry ${st.current.id}: ${st.current.sample_id} (${st.current.plan})` : "";
  document.title = `${st.state} · goniofrost serve`;
  showPose(st.pose || {});
  showLamp(st.lamp || {});
}

function showPose(pose) {
  for (const [name, deg] of Object.entries(pose)) {
    const cell = $(`pos-${name}`);
    if (cell) cell.textContent = deg == null ? "unread" : `${deg.toFixed(2)}°`;
  }
  if (ui.status) ui.status.pose = pose;
}

function showLamp(lamp) {
  $("lamp-state").textContent = lamp.on == null ? "unknown" : lamp.on ? "on" : "off";
  $("photodiode").textContent = lamp.photodiode == null ? "–" : String(lamp.photodiode);
}

// A status read is shown unless an event newer than it was shown meanwhile.
async function refreshStatus() {
  const st = await (await fetch("/api/status", { cache: "no-store" })).json();
  if (st.events - 1 >= ui.lastSeq) showStatus(st);
  return st;
}

function onRecord(event) {
  const record = JSON.parse(event.data);
  ui.lastSeq = Math.max(ui.lastSeq, record.seq);
  if (record.type === "state") {
    showStatus({ ...ui.status, state: record.state, reason: record.reason });
    refreshStatus().catch(() => {});  // held and the current entry are in the status only
    refreshQueue();
  } else if (record.type === "pose") {
    showPose(record.pose);
    showLamp(record.lamp);
  } else if (record.type === "lamp") {
    showLamp({ ...(ui.status && ui.status.lamp), on: record.on });
  } else if (record.type === "pause_asked") {
    $("reason").textContent = "pause asked: at the next safe point";
  } else if (record.type === "suspend_asked") {
    $("reason").textContent = `suspending: ${record.reason}`;
  } else if (record.type === "queue" || record.type === "entry_ended") {
    refreshQueue();
  }
}

async function connect() {
  try {
    const st = await refreshStatus();
    const source = new EventSource(`/api/events?since=${st.events}`);
    for (const kind of ["state", "pose", "lamp", "pause_asked", "suspend_asked", "queue", "entry_ended"]) {
      source.addEventListener(kind, onRecord);
    }
    source.onopen = () => { $("connection").textContent = "live"; $("connection").classList.remove("lost"); };
    source.onerror = () => {  // reconnect from a fresh status (the stream restarts at its number)
      source.close();
      $("connection").textContent = "connection lost; retrying…";
      $("connection").classList.add("lost");
      setTimeout(connect, 2000);
    };
    ui.source = source;
  } catch (err) {
    $("connection").textContent = "the server does not answer; retrying…";
    setTimeout(connect, 2000);
  }
}

// ----- the rig: axes with their limits ----------------------------------------------------------------
function buildAxes(rig) {
  $("rig-name").textContent = `rig ${rig.name}${rig.simulated ? " (simulated)" : ""}`;
  $("material-field").hidden = !rig.simulated;
  const ladder = rig.camera.exposures_s;
  $("exposure").value = ladder[Math.floor(ladder.length / 2)];
  $("axis-table").tBodies[0].replaceChildren(...rig.axes.map((axis) => {
    const [lo, hi] = axis.limits_deg;
    const row = el("tr", null, { "data-axis": axis.name });
    const limits = el("td", `${lo}° to ${hi}°`, axis.note ? { title: axis.note } : {});
    if (axis.note) limits.append(el("br"), el("span", axis.note, { class: "muted small" }));
    const target = el("input", null, { type: "number", step: "0.1", size: "7", id: `target-${axis.name}`,
                                       "aria-label": `${axis.name} target (deg)` });
    const move = el("button", "Move", { type: "button", id: `move-${axis.name}` });
    move.addEventListener("click", () => moveAxis(axis.name, Number(target.value)));
    const jogs = el("td", null, { class: "control" });
    for (const sign of [-1, 1]) {
      const jog = el("button", sign < 0 ? "−" : "+", { type: "button", id: `jog-${sign < 0 ? "minus" : "plus"}-${axis.name}` });
      jog.addEventListener("click", () => {
        const now = ui.status && ui.status.pose[axis.name];
        if (now != null) moveAxis(axis.name, now + sign * Number($("jog-step").value));
      });
      jogs.append(jog);
    }
    const moveCell = el("td", null, { class: "control" });
    moveCell.append(target, " ", move);
    row.append(el("td", axis.name), el("td", "–", { id: `pos-${axis.name}`, class: "num" }), limits, moveCell, jogs);
    return row;
  }));
  if (ui.status) showPose(ui.status.pose || {});
}

async function moveAxis(name, deg) {
  await control("POST", "/api/move", { targets: { [name]: deg } }, $("move-error"));
}

// ----- the queue ------------------------------------------------------------------------------------
let queueAsked = 0;

async function refreshQueue() {
  const asked = ++queueAsked;
  const entries = await (await fetch("/api/queue", { cache: "no-store" })).json().catch(() => null);
  if (entries && asked === queueAsked) showQueue(entries);  // only the latest answer is shown
}

function showQueue(entries) {
  const pending = entries.filter((e) => e.state === "pending").map((e) => e.id);
  $("queue-table").tBodies[0].replaceChildren(...entries.map((e) => {
    const row = el("tr", null, { "data-id": e.id, "data-state": e.state });
    const session = el("td");
    if (e.session) {
      const name = e.session.split("/").pop();
      session.append(el("a", name, { href: `/s/${encodeURIComponent(name)}/` }));
    }
    const result = e.result ? JSON.parse(e.result) : null;
    if (result && result.reason) session.append(el("br"), el("span", result.reason, { class: "muted small" }));
    const actions = el("td", null, { class: "control" });
    const k = pending.indexOf(e.id);
    if (k >= 0) {
      const up = el("button", "↑", { type: "button", title: "earlier", "data-action": "up" });
      const down = el("button", "↓", { type: "button", title: "later", "data-action": "down" });
      const remove = el("button", "Remove", { type: "button", "data-action": "remove" });
      up.disabled = k === 0;
      down.disabled = k === pending.length - 1;
      up.addEventListener("click", () => reorder(e.id, pending[k - 1]));
      down.addEventListener("click", () => reorder(e.id, k + 2 < pending.length ? pending[k + 2] : null));
      remove.addEventListener("click", () => removeEntry(e.id));
      actions.append(up, down, remove);
    }
    row.append(el("td", String(e.id)), el("td", e.sample_id), el("td", e.plan), el("td", e.operator || "–"),
               el("td", e.state, { class: "entry-state" }),
               el("td", e.target_error == null ? "–" : `${e.target_error} (${e.confidence})`), session, actions);
    return row;
  }));
  const done = entries.length - pending.length;
  $("queue-count").textContent = `${pending.length} pending, ${done} running or ended`;
}

async function reorder(id, before) {
  if (await control("POST", `/api/queue/${id}/move`, { before }, $("queue-error"))) refreshQueue();
}

async function removeEntry(id) {
  if (await control("DELETE", `/api/queue/${id}`, {}, $("queue-error"))) refreshQueue();
}

async function addEntry(event) {
  event.preventDefault();
  const form = $("add-form"), body = {};
  for (const input of form.querySelectorAll("input")) {
    if (input.closest("[hidden]") || input.value.trim() === "") continue;  // left out: the server's default
    body[input.name] = input.type === "number" ? Number(input.value) : input.value.trim();
  }
  if ($("operator").value.trim()) body.operator = $("operator").value.trim();
  if (await control("POST", "/api/queue", body, $("queue-error"))) {
    form.elements.sample_id.value = "";
    refreshQueue();
  }
}

// ----- the camera view --------------------------------------------------------------------------------
async function takeFrame() {
  const body = { exposure_s: Number($("exposure").value) };
  if (!$("auto-levels").checked) { body.black = Number($("black").value); body.white = Number($("white").value); }
  $("take-frame").disabled = true;
  try {
    const answer = await control("POST", "/api/camera", body, $("camera-error"));
    if (!answer) return;
    const info = JSON.parse(answer.headers.get("X-Info") || "{}");
    const img = $("camera-img"), old = img.src;
    img.src = URL.createObjectURL(await answer.blob());
    img.hidden = false;
    if (old.startsWith("blob:")) URL.revokeObjectURL(old);
    const levels = `${info.auto ? "auto levels" : "levels"}: black ${info.black}, white ${info.white}`;
    $("camera-caption").textContent = `exposure ${info.exposure_s} s · ${levels} · ` +
      `${(100 * info.saturated_fraction).toFixed(2)} % of the frame saturated (red) · ${info.width} × ${info.height} px`;
    if (info.auto) { $("black").value = info.black; $("white").value = info.white; }
  } finally {
    $("take-frame").disabled = false;
  }
}

// ----- start ------------------------------------------------------------------------------------------
function wireControls() {
  document.body.dataset.control = "yes";
  $("operator").value = sessionStorage.getItem("goniofrost-operator") || "";
  $("operator").addEventListener("change", () => sessionStorage.setItem("goniofrost-operator", $("operator").value));
  for (const what of ["pause", "resume", "stop"]) {
    $(what).addEventListener("click", () => control("POST", `/api/${what}`, {}, $("run-error")));
  }
  $("home").addEventListener("click", () => control("POST", "/api/home", {}, $("move-error")));
  $("lamp-on").addEventListener("click", () => control("POST", "/api/lamp", { on: true }, $("lamp-error")));
  $("lamp-off").addEventListener("click", () => control("POST", "/api/lamp", { on: false }, $("lamp-error")));
  $("add-form").addEventListener("submit", addEntry);
  $("take-frame").addEventListener("click", takeFrame);
  $("auto-levels").addEventListener("change", () => {
    $("black").disabled = $("white").disabled = $("auto-levels").checked;
  });
}

async function start() {
  if (ui.token) wireControls();
  else $("read-only").hidden = false;
  connect();
  refreshQueue();
  setInterval(() => { refreshStatus().catch(() => {}); }, POLL_MS);
  ui.rig = await (await fetch("/api/rig", { cache: "no-store" })).json();
  buildAxes(ui.rig);
}

window.goniofrostServe = ui;
start();
