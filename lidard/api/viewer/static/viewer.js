// lidard web viewer: watches the daemon over its own REST API (same rules as any client: reads are
// open, starting or cancelling needs the control lease, sent as X-Lidard-Lease).
// window.viewer exposes the page's state (scanId, pointCount, complete, ...) for tests and the console.
import { Cloud, colorOf } from "/viewer/cloud.js";
import * as panels from "/viewer/panels.js";
import { StreamPlayer, renderStreams } from "/viewer/stream.js";

const FIELDS = ["x", "y", "z", "range", "velocity", "intensity", "snr_db", "row", "col", "t", "valid"];
const $ = (id) => document.getElementById(id);

const viewer = window.viewer = {
  lease: null, holder: null, simulated: false, refreshes: 0,
  scanId: null, pointCount: 0, complete: false, scanState: null, lastError: null,
  streamId: null, frameIndex: null, framesShown: 0, frameRateHz: null, streamState: null,
  cloud: new Cloud($("cloud"), FIELDS),
};

async function api(path, opts = {}) {
  const headers = { ...(opts.headers || {}) };
  if (viewer.lease) headers["X-Lidard-Lease"] = viewer.lease;
  if (opts.json !== undefined) { headers["Content-Type"] = "application/json"; opts.body = JSON.stringify(opts.json); }
  const r = await fetch(path, { ...opts, headers });
  if (!r.ok) {
    let detail = r.statusText;
    try { const j = await r.json(); detail = typeof j.detail === "string" ? j.detail : JSON.stringify(j.detail); } catch (e) { /* not JSON */ }
    const err = new Error(`${r.status}: ${detail}`); err.status = r.status; throw err;
  }
  return r;
}
const getJSON = async (path) => (await api(path)).json();

// ---- the point cloud of one scan, fetched incrementally ---------------------------------------
let pulling = false, pullAgain = false, events = null;

async function pullPoints() {
  if (pulling) { pullAgain = true; return; }
  pulling = true;
  try {
    do {
      pullAgain = false;
      const id = viewer.scanId;
      const r = await api(`/scans/${id}/points/live?since=${viewer.pointCount}`);
      if (id !== viewer.scanId) break;  // the user switched scans meanwhile
      const rows = new Float32Array(await r.arrayBuffer());
      viewer.cloud.append(rows);
      viewer.pointCount = viewer.cloud.count;
      viewer.complete = r.headers.get("X-Lidard-Complete") === "true";
      if (rows.length && !viewer.complete) pullAgain = true;  // more may be waiting (limit)
      $("point-count").textContent = `${viewer.pointCount} points${viewer.complete ? "" : " …"}`;
      drawLegend();
    } while (pullAgain);
  } catch (e) {
    viewer.lastError = String(e);
  } finally {
    pulling = false;
  }
}

function showScan(id) {
  if (events) { events.close(); events = null; }
  player.stop();
  viewer.scanId = id; viewer.pointCount = 0; viewer.complete = false; viewer.scanState = null;
  viewer.cloud.clear();
  $("scan-label").textContent = `scan ${id}`;
  $("picked").textContent = "click a point to see its fields";
  // progress events say when new points exist; the end event says the count is final
  events = new EventSource(`/scans/${id}/events`);
  events.addEventListener("progress", (m) => { viewer.scanState = "running"; pullPoints(); });
  events.addEventListener("end", (m) => {
    viewer.scanState = JSON.parse(m.data).state;
    events.close(); events = null;
    pullPoints();
    refresh();
  });
  pullPoints();
}

// ---- a stream: its frames one cloud at a time (stream.js) ----------------------------------------
const player = new StreamPlayer(viewer, (path) => api(path), {
  label: $("scan-label"), counter: $("frame-counter"), points: $("point-count"), onDrawn: () => drawLegend(),
});
const autoShown = new Set();   // running streams shown once on their own; the user may switch away

function showStream(id) {
  if (events) { events.close(); events = null; }
  viewer.scanId = null; viewer.scanState = null; viewer.pointCount = 0; viewer.complete = false;
  viewer.cloud.clear();
  $("picked").textContent = "click a point to see its fields";
  autoShown.add(id);
  player.show(id);
}

// ---- control lease --------------------------------------------------------------------------
// The lease lives in this tab's sessionStorage, so a reload keeps control instead of orphaning the
// lease until it lapses. Leaving the page (close or reload: pagehide cannot tell them apart) sends
// its release with fetch keepalive; a reload then takes control again by handing the stored lease
// over to itself (POST /control/handover: a fresh lease, the old one void, so an old page's late
// release cannot free the new one), or, when the release came first, by a plain POST /control.
const LEASE_KEY = "lidard.lease";
// Bumped whenever this page's lease changes: an answer of GET /control asked for before that change
// (a refresh still in flight when the user took control) says nothing about the new lease.
let leaseSeq = 0;
const CLIENT = "web viewer";

function keepLease(lease, holder) {
  leaseSeq++;
  viewer.lease = lease; viewer.holder = holder;
  if (lease) sessionStorage.setItem(LEASE_KEY, JSON.stringify({ lease, holder }));
  else sessionStorage.removeItem(LEASE_KEY);
}

async function takeControl() {
  try {
    const r = await (await api("/control", { method: "POST", json: { client: CLIENT } })).json();
    keepLease(r.lease, r.holder);
    showControl({ held: true, holder: r.holder });
  } catch (e) { $("scan-error").textContent = String(e); }
  refresh();
}

async function releaseControl() {
  try { await api("/control", { method: "DELETE" }); } catch (e) { /* already gone */ }
  keepLease(null, null);
  refresh();
}

async function restoreControl() {
  let kept = null;
  try { kept = JSON.parse(sessionStorage.getItem(LEASE_KEY) || "null"); } catch (e) { /* unreadable */ }
  if (!kept || !kept.lease) return;
  viewer.lease = kept.lease;
  try {
    const r = await (await api("/control/handover", { method: "POST", json: { client: CLIENT } })).json();
    keepLease(r.lease, r.holder);
  } catch (e) {
    viewer.lease = null;
    if (e.status === 409) await takeControl();   // released on the way out, and nobody took it since
    else keepLease(null, null);                  // lapsed, or another client holds it now
  }
}

addEventListener("pagehide", () => {
  if (!viewer.lease) return;
  // keepalive: the request outlives the page (the browser's limit on such bodies is far above this)
  fetch("/control", { method: "DELETE", keepalive: true, headers: { "X-Lidard-Lease": viewer.lease } });
});

async function startScan(ev) {
  ev.preventDefault();
  const f = new FormData($("scan-form")), n = (k) => Number(f.get(k));
  const body = { pattern: f.get("pattern"), averages: n("averages"), max_range_m: n("max_range_m"), formats: ["npz"] };
  if (body.pattern === "roi") { body.rows = [n("row0"), n("row1")]; body.cols = [n("col0"), n("col1")]; }
  $("scan-error").textContent = "";
  try {
    const s = await (await api("/scans", { method: "POST", json: body })).json();
    showScan(s.id);
  } catch (e) { $("scan-error").textContent = String(e); viewer.lastError = String(e); }
  refresh();
}

async function cancelScan(id) {
  try { await api(`/scans/${id}`, { method: "DELETE" }); } catch (e) { $("scan-error").textContent = String(e); }
  refresh();
}

// ---- periodic refresh of the panels -------------------------------------------------------------
function showControl(control) {
  const mine = !!(viewer.lease && control.held && control.holder === viewer.holder);
  if (viewer.lease && !mine) keepLease(null, null);  // expired or taken over
  $("control-status").textContent = control.held ? `control: ${mine ? "you" : control.holder}` : "control: free";
  $("control-take").hidden = mine; $("control-release").hidden = !mine;
  $("scan-start").disabled = !mine;
  return mine;
}

// Each panel refreshes on its own, so a slow device check never holds up the queue or the controls.
let calTick = 0;
let wasRunning = false;   // a scan was running at the last refresh: the one after it ends reads the calibrations
async function refresh() {
  const seq = leaseSeq;
  try {
    const [health, control, list, streams] = await Promise.all([getJSON("/health"), getJSON("/control"),
      getJSON("/scans?limit=12"), getJSON("/streams")]);
    viewer.simulated = health.simulated;
    $("health").textContent = `${health.version} · ${health.simulated ? "simulated bench" : "hardware"} · ${health.status}`;
    $("linearization").textContent = panels.linearizationLine(health.linearization);
    // a stale answer (the lease changed while it was on its way) neither voids nor shows the lease
    const mine = seq === leaseSeq ? showControl(control) : !!viewer.lease;
    panels.renderQueue($("queue"), list.scans, { canAct: mine, onCancel: cancelScan, onShow: showScan, shownId: viewer.scanId });
    renderStreams($("streams"), streams.streams.slice(0, 8), { onShow: showStream, shownId: viewer.streamId });
    if (streams.running && !autoShown.has(streams.running)) showStream(streams.running);
    else if (!viewer.scanId && !viewer.streamId && list.scans.length) showScan(list.running || list.scans[0].id);
    refreshSlow(health.simulated, calTick++ % 5 === 0 || !!list.running || wasRunning);
    wasRunning = !!list.running;
  } catch (e) {
    $("health").textContent = `daemon unreachable (${e})`;
  } finally {
    viewer.refreshes++;   // panel refreshes finished (tests wait on it)
  }
}

let slowBusy = false;
async function refreshSlow(simulated, withCalibrations) {
  if (slowBusy) return;
  slowBusy = true;
  try {
    const devices = (await getJSON("/devices")).devices;
    panels.renderDevices($("devices"), devices);
    if (!viewer.scanner) viewer.scanner = await getJSON("/scanner");
    viewer.unbondedRows = panels.unbondedRows(viewer.scanner, devices);
    $("rows-note").textContent = panels.rowsNote(viewer.scanner, viewer.unbondedRows);
    panels.renderFaults($("faults"), simulated ? (await getJSON("/sim/faults")).faults : [], simulated);
    if (withCalibrations || !viewer.calibrationsShown) {
      const cals = await getJSON("/calibration/history?limit=5");
      viewer.calibrationsShown = true;
      panels.renderCalibrations($("calibrations"), cals);
      panels.plotConvergence($("convergence"), cals);
    }
  } catch (e) {
    viewer.lastPanelError = String(e);
  } finally {
    slowBusy = false;
  }
}

// The colour bar: the map of the current mode from its low to its high limit, with the unit.
const UNITS = { range: "range, m", velocity: "radial velocity, m/s (+ receding)", snr_db: "SNR, dB",
  intensity: "amplitude, V" };
function drawLegend() {
  const [lo, hi] = viewer.cloud.colorLimits || [0, 0], mode = viewer.cloud.mode;
  const c = $("colorbar"), g = c.getContext("2d");
  for (let x = 0; x < c.width; x++) {
    const [r, gr, b] = colorOf(mode, x / (c.width - 1));
    g.fillStyle = `rgb(${255 * r},${255 * gr},${255 * b})`; g.fillRect(x, 0, 1, c.height);
  }
  $("legend-lo").textContent = lo.toPrecision(3); $("legend-hi").textContent = hi.toPrecision(3);
  $("legend-unit").textContent = UNITS[mode];
  viewer.legend = { mode, lo, hi, unit: UNITS[mode] };
}

// Rows/cols apply to an ROI only: raster and serpentine scan every bonded pixel of the array.
function followPattern() {
  const pattern = $("scan-form").elements.pattern.value, roi = pattern === "roi";
  $("roi-fields").disabled = !roi;
  $("pattern-note").textContent = roi ? "" : `${pattern}: the whole array (rows/cols apply to roi only)`;
}

viewer.cloud.onPick = (p) => {
  $("picked").textContent = p === null ? "no point there" : FIELDS.map((f) =>
    `${f.padEnd(9)} ${["row", "col", "valid"].includes(f) ? p[f] : p[f].toPrecision(5)}`).join("\n");
  viewer.picked = p;
};
$("color-mode").addEventListener("change", (e) => { viewer.cloud.setMode(e.target.value); drawLegend(); });
$("control-take").addEventListener("click", takeControl);
$("control-release").addEventListener("click", releaseControl);
$("scan-form").addEventListener("submit", startScan);
$("scan-form").elements.pattern.addEventListener("change", followPattern);
followPattern();
viewer.showScan = showScan;
viewer.showStream = showStream;
restoreControl().finally(() => {
  viewer.ready = true;
  refresh();
  setInterval(refresh, 1000);
});
