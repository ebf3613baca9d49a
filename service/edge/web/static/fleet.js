// servowatch fleet page: reads /api/fleet (ranked units) and /api/unit?name= (one unit's
// history) and draws them. Every value from the store is set as text, never as markup.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const STATUS_LABEL = { critical: "critical", watch: "watch", ok: "ok", uncommissioned: "not commissioned" };
const BAR_W = 220, BAR_H = 16;
let fleet = null;
let live = null;
let selected = null;

const $ = (id) => document.getElementById(id);

function el(tag, attrs, text) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (text !== undefined && text !== null) e.textContent = String(text);
  return e;
}

function svg(tag, attrs, text) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, String(v));
  if (text !== undefined) e.textContent = String(text);
  return e;
}

function num(v) { return typeof v === "number" && isFinite(v) ? v : null; }
function fmt(v, digits, scale) {
  const n = num(v);
  return n === null ? "-" : (n * (scale || 1)).toFixed(digits);
}

function niceTicks(max, n) {
  // about n round ticks over [0, max]: steps of 1, 2 or 5 x 10^k
  const raw = max / Math.max(n, 1);
  const p = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * p).find((s) => s >= raw) || raw;
  const out = [];
  for (let v = 0; v <= max * (1 + 1e-9); v += step) out.push(v);
  return { ticks: out, step };
}

function tickText(v, step) { return v.toFixed(step >= 1 ? 0 : Math.min(3, Math.ceil(-Math.log10(step)))); }

function banner(text) {
  const b = $("banner");
  b.hidden = !text;
  b.textContent = text || "";
}

async function getJSON(url) {
  const r = await fetch(url, { cache: "no-store" });
  let body = null;
  try { body = await r.json(); } catch (e) { body = null; }
  if (!r.ok) throw new Error((body && body.error) || `${url}: HTTP ${r.status}`);
  return body;
}

function rulText(u) {
  const iv = u.rul_interval;
  const rul = u.rul || {};
  if (!u.rul) return "-";
  if (rul.status && rul.status !== "ok") return rul.status;
  if (!iv || num(iv.median) === null) return "none predicted";
  const unit = iv.unit === "flights" ? "flights" : "h";
  const days = num(iv.median_days) === null ? "" : ` (~${fmt(iv.median_days, 0)} d)`;
  return `${fmt(iv.median, 0)} [${fmt(iv.lo, 0)}-${fmt(iv.hi, 0)}] ${unit}${days}`;
}

function lifeText(u) {
  // flights so far, or operating hours: the life axis the unit's history supports
  const l = u.life;
  if (!l || num(l.value) === null) return "-";
  return l.unit === "flights" ? `${fmt(l.value, 0)} flights` : `${fmt(l.value, 1)} h`;
}

function flightsText(u) {
  const iv = u.rul_interval;
  if (!iv || num(iv.median_flights) === null) return "-";
  return `${fmt(iv.median_flights, 0)} [${fmt(iv.lo_flights, 0)}-${fmt(iv.hi_flights, 0)}]`;
}

function intervalBar(u, axisMax, horizon) {
  // the RUL's 90 % interval on the fleet's common axis [0, axisMax] (flights or operating hours)
  const s = svg("svg", { width: BAR_W, height: BAR_H, class: "ivl-svg" });
  const x = (h) => Math.min(Math.max(h, 0), axisMax) / axisMax * (BAR_W - 2) + 1;
  s.appendChild(svg("line", { x1: 1, x2: BAR_W - 1, y1: BAR_H / 2, y2: BAR_H / 2, class: "grid" }));
  if (num(horizon) !== null) {
    s.appendChild(svg("line", { x1: x(horizon), x2: x(horizon), y1: 0, y2: BAR_H, class: "horizon" }));
  }
  const iv = u.rul_interval;
  if (iv && num(iv.median) !== null) {
    const lo = num(iv.lo) === null ? iv.median : iv.lo;
    const hi = num(iv.hi) === null ? axisMax : iv.hi;
    const r = svg("rect", {
      x: x(lo), y: 3, width: Math.max(x(hi) - x(lo), 2), height: BAR_H - 6,
      class: "ivl" + (u.status === "critical" ? " critical" : ""),
    });
    r.appendChild(svg("title", {}, `RUL ${rulText(u)}`));
    s.appendChild(r);
    s.appendChild(svg("line", { x1: x(iv.median), x2: x(iv.median), y1: 1, y2: BAR_H - 1, class: "ivl-med" }));
  }
  return s;
}

function renderCards(data) {
  const c = $("cards");
  c.replaceChildren();
  const card = (cls, n, label) => {
    const d = el("div", { class: "card " + cls, "data-status": cls });
    d.appendChild(el("b", {}, n));
    d.appendChild(el("span", {}, label));
    c.appendChild(d);
  };
  card("all", data.actuators, "units");
  for (const s of ["critical", "watch", "ok", "uncommissioned"]) card(s, data.counts[s] || 0, STATUS_LABEL[s]);
  card("rul", data.with_rul, "with a RUL");
}

function renderTable() {
  const data = fleet;
  const tbody = $("fleet").tBodies[0];
  tbody.replaceChildren();
  const q = $("filter").value.trim().toLowerCase();
  const horizon = num(data.horizon);
  const unit = data.horizon_unit === "flights" ? "flights" : "h";
  // a common axis for every bar: the planning horizon, out to twice it where an interval ends later
  let axisMax = 100;
  if (horizon !== null) {
    const his = data.fleet.map((u) => u.rul_interval && num(u.rul_interval.hi)).filter((h) => h !== null && h !== undefined);
    axisMax = Math.min(2 * horizon, Math.max(horizon, ...his));
  }
  $("axis").textContent = `(0-${axisMax.toFixed(0)} ${unit}${horizon === null ? "" : `, horizon ${horizon.toFixed(0)} ${unit}`})`;
  let shown = 0;
  for (const u of data.fleet) {
    if (q && !u.actuator.toLowerCase().includes(q)) continue;
    shown += 1;
    const tr = el("tr", { "data-actuator": u.actuator, "data-rank": u.rank, "data-status": u.status });
    if (u.actuator === selected) tr.classList.add("selected");
    const last = u.last || {};
    const tr_ = u.trend || {};
    const rate = u.trend_rate;  // the C_Lk-ratio trend on the unit's life axis
    const slope = rate ? num(rate.value) : null;
    tr.appendChild(el("td", { class: "rank" }, u.rank));
    tr.appendChild(el("td", { class: "unit" }, u.actuator));
    const st = el("td", { class: "status", title: u.status_reason || "" });
    st.appendChild(el("span", { class: "badge " + u.status }, STATUS_LABEL[u.status] || u.status));
    tr.appendChild(st);
    // the latest observable C_Lk ratio in the unit's life order (the fleet view's, rul's)
    tr.appendChild(el("td", { class: "ratio" }, fmt(u.last_ratio, 3)));
    tr.appendChild(el("td", { class: "trend " + (tr_.label || "") },
      slope === null ? "-" : `${tr_.label || ""} ${slope >= 0 ? "+" : ""}${slope.toFixed(2)} ${rate.unit}`.trim()));
    tr.appendChild(el("td", { class: "psr" }, fmt(last.p_sr_min, 2, 1e-6)));
    tr.appendChild(el("td", { class: "rul" }, rulText(u)));
    const bar = el("td", { class: "bar" });
    bar.appendChild(intervalBar(u, axisMax, horizon));
    tr.appendChild(bar);
    tr.appendChild(el("td", { class: "flights" }, flightsText(u)));
    tr.appendChild(el("td", { class: "phor" }, u.rul_interval ? fmt(u.rul_interval.p_horizon, 2) : "-"));
    tr.appendChild(el("td", { class: "alarms" }, Math.max(u.alarms || 0, u.alarm_events || 0)));
    tr.appendChild(el("td", { class: "life" }, lifeText(u)));
    tr.appendChild(liveCell(u.actuator));
    tr.addEventListener("click", () => { location.hash = "unit=" + encodeURIComponent(u.actuator); });
    tbody.appendChild(tr);
  }
  $("shown").textContent = q ? `${shown} of ${data.fleet.length} shown` : "";
  $("empty").hidden = data.fleet.length > 0;
}

function liveCell(name) {
  // which daemon monitors the unit now, from /api/live (hidden when the page has no Zenoh)
  const td = el("td", { class: "c-live" });
  const lu = live && live.enabled && live.units ? live.units[name] : null;
  if (!lu) {
    td.textContent = live && live.enabled ? "not monitored" : "-";
    td.dataset.live = "none";
    return td;
  }
  if (lu.unmonitored) {
    // measurements arrive but no group member publishes its health: nobody watches it
    td.dataset.live = "unmonitored";
    td.appendChild(el("span", { class: "dot unmonitored" }));
    td.appendChild(document.createTextNode(`UNMONITORED (owner ${lu.owner || "none"})`));
    td.title = "its measurements arrive, but no monitor-group member publishes its health";
    return td;
  }
  const state = lu.silent ? "silent" : "receiving";
  td.dataset.live = state;
  td.appendChild(el("span", { class: "dot " + state }));
  td.appendChild(document.createTextNode(`${lu.daemon} (${state})`));
  td.title = `${lu.samples} samples, ${lu.bad || 0} bad, ${lu.dropped || 0} dropped, ${lu.missed || 0} missed` +
    (lu.alarms.length ? `; alarm ${lu.alarms.join(", ")}` : "");
  return td;
}

function renderDaemons() {
  const box = $("daemons");
  const on = !!(live && live.enabled);
  document.body.classList.toggle("live-off", !on);
  box.hidden = !on;
  if (!on) return;
  const list = $("daemon-list");
  list.replaceChildren();
  $("live-age").textContent = live.error ? `(status query failed: ${live.error})`
    : (num(live.age_s) === null ? "(asking...)" : `(asked ${live.age_s.toFixed(0)} s ago)`);
  if (!live.daemons.length) list.appendChild(el("span", { class: "daemon none" }, "no daemon answers"));
  for (const d of live.daemons) {
    const c = el("div", { class: "daemon " + (d.state || ""), "data-daemon": d.name || d.key });
    c.appendChild(el("b", {}, d.name || d.key));
    c.appendChild(el("span", { class: "st" }, d.state || "-"));
    c.appendChild(el("div", {},
      `${d.units} units, ${d.samples} samples, ${d.dropped} dropped, ${d.bad} bad, ${d.missed} missed` +
      (num(d.latency_p99_ms) === null ? "" : `, p99 ${d.latency_p99_ms.toFixed(1)} ms`) +
      (d.silent && d.silent.length ? `, silent: ${d.silent.join(", ")}` : "")));
    if (d.log_failure) c.appendChild(el("div", { class: "rising" }, `log failed: ${d.log_failure}`));
    if (d.unmonitored && d.unmonitored.length) {
      c.appendChild(el("div", { class: "rising" }, `unmonitored: ${d.unmonitored.join(", ")}`));
    }
    // what the reply check left out (service/edge/status.py): named, the rest shown
    if (d.bad_units && d.bad_units.length) {
      c.appendChild(el("div", { class: "rising" }, `bad units (not shown): ${d.bad_units.join(", ")}`));
    }
    if (d.bad_fields && d.bad_fields.length) {
      c.appendChild(el("div", { class: "rising" }, `bad fields (not shown): ${d.bad_fields.join(", ")}`));
    }
    list.appendChild(c);
  }
}

async function loadLive() {
  try {
    live = await getJSON("/api/live");
  } catch (e) {
    // the page's own server did not answer: keep whether live status is on, drop the rest
    live = { enabled: !!(live && live.enabled), daemons: [], units: {}, error: e.message };
  }
  renderDaemons();
}

async function loadFleet() {
  await loadLive();
  try {
    fleet = await getJSON("/api/fleet");
    banner("");
    $("store").textContent = fleet.store;
    $("updated").textContent = new Date(fleet.generated_s * 1000).toLocaleTimeString();
    renderCards(fleet);
    renderTable();
    document.body.dataset.fleetReady = "1";
  } catch (e) {
    // keep the last table, say that it is stale and why
    banner(`store not reachable, showing the last good data: ${e.message}`);
    document.body.dataset.fleetError = e.message;
  }
}

function chart(unit) {
  // C_Lk ratio per period against the unit's life axis (the store summary's life_axis:
  // flights flown when its history counts flights, else cumulative operating hours; each
  // period's place on it is its `life`), +-1 sigma, the failure threshold and the RUL's 90 %
  // interval where the trend would meet it, on that same axis (rul_on_axis)
  const W = 760, H = 290, L = 52, R = 16, T = 24, B = 34;
  const s = svg("svg", { width: W, height: H, id: "history", role: "img" });
  const flights = unit.life_axis === "flights";
  const pts = unit.periods.filter((p) => num(p.c_lk_ratio) !== null && num(p.life) !== null);
  const rul = unit.rul || {};
  const thr = num(rul.threshold_ratio);
  // the RUL counts from where the history ended when it was computed (iv.now), which
  // newer periods may have passed since
  const iv = unit.rul_on_axis;
  const lives = unit.periods.map((p) => num(p.life)).filter((t) => t !== null);
  const tLast = lives.length ? lives[lives.length - 1] : 0;
  let tMax = Math.max(tLast, 1e-6);
  if (iv) tMax = Math.max(tMax, iv.now, iv.now + iv.hi);
  tMax *= 1.04;
  let yMax = 1.2;
  for (const p of pts) yMax = Math.max(yMax, p.c_lk_ratio + (num(p.c_lk_ratio_sigma) || 0));
  if (thr !== null) yMax = Math.max(yMax, thr * 1.08);
  const yMin = 0;
  const x = (t) => L + (t / tMax) * (W - L - R);
  const y = (v) => H - B - ((v - yMin) / (yMax - yMin)) * (H - T - B);
  const yt = niceTicks(yMax, 5);
  for (const v of yt.ticks) {
    s.appendChild(svg("line", { x1: L, x2: W - R, y1: y(v), y2: y(v), class: "grid" }));
    s.appendChild(svg("text", { x: L - 6, y: y(v) + 4, "text-anchor": "end" }, tickText(v, yt.step)));
  }
  const xt = niceTicks(tMax, 6);
  for (const t of xt.ticks) {
    s.appendChild(svg("line", { x1: x(t), x2: x(t), y1: H - B, y2: H - B + 4, class: "axis" }));
    s.appendChild(svg("text", { x: x(t), y: H - B + 16, "text-anchor": "middle" }, tickText(t, xt.step)));
  }
  s.appendChild(svg("line", { x1: L, x2: W - R, y1: H - B, y2: H - B, class: "axis" }));
  s.appendChild(svg("line", { x1: L, x2: L, y1: T, y2: H - B, class: "axis" }));
  s.appendChild(svg("text", { x: (L + W - R) / 2, y: H - 4, "text-anchor": "middle", class: "x-label", "data-axis": flights ? "flights" : "hours" },
    flights ? "flights" : "operating hours"));
  s.appendChild(svg("text", { x: L, y: T - 10 }, "C_Lk / baseline, per operating period (1 sigma bars; red: alarm)"));
  s.appendChild(svg("line", { x1: L, x2: W - R, y1: y(1), y2: y(1), class: "baseline" }));
  if (thr !== null) {
    s.appendChild(svg("line", { x1: L, x2: W - R, y1: y(thr), y2: y(thr), class: "threshold" }));
    s.appendChild(svg("text", { x: L + 6, y: y(thr) - 5 }, `failure threshold ${thr.toFixed(2)}`));
    if (iv) {
      s.appendChild(svg("rect", {
        x: x(iv.now + iv.lo), y: y(thr) - 9, width: Math.max(x(iv.now + iv.hi) - x(iv.now + iv.lo), 2), height: 18, class: "rul-band",
      }));
      s.appendChild(svg("line", {
        x1: x(iv.now + iv.median), x2: x(iv.now + iv.median), y1: y(thr) - 11, y2: y(thr) + 11, class: "rul-median",
      }));
    }
  }
  for (const p of pts) {
    const sig = num(p.c_lk_ratio_sigma);
    if (sig !== null && sig > 0) {
      s.appendChild(svg("line", { x1: x(p.life), x2: x(p.life), y1: y(p.c_lk_ratio - sig), y2: y(p.c_lk_ratio + sig), class: "err" }));
    }
    const c = svg("circle", { cx: x(p.life), cy: y(p.c_lk_ratio), r: 3, class: "pt" + (p.alarms ? " alarm" : "") });
    const pool = num(p.c_lk_pooled) !== null ? `, pooled C_Lk ${p.c_lk_pooled.toExponential(2)} +- ${(num(p.c_lk_pooled_sigma) || 0).toExponential(1)}` : "";
    const at = flights ? `flight ${p.life.toFixed(0)} (${p.t_h.toFixed(2)} h)` : `${p.t_h.toFixed(2)} h`;
    c.appendChild(svg("title", {}, `${at}: ${p.c_lk_ratio.toFixed(3)}${pool}${p.alarms ? ", alarm" : ""}`));
    s.appendChild(c);
  }
  return s;
}

// the unit's usage: per operating hour (the fleet row's totals over the periods that carry
// it) and per flight (the unit view's mean over its flights)
function usageText(tot, fl) {
  const parts = [];
  if (tot && num(tot.travel_m_per_h) !== null) {
    parts.push(`${fmt(tot.travel_m_per_h, 2)} m travel, ${fmt(tot.load_travel_j_per_h, 1, 1e-3)} kJ load-weighted travel, ${fmt(tot.reversals_per_h, 0)} reversals per operating hour`);
  }
  if (fl && fl.flights && num(fl.travel_m) !== null) {
    parts.push(`${fmt(fl.travel_m, 2)} m, ${fmt(fl.load_travel_j, 1, 1e-3)} kJ, ${fmt(fl.reversals, 0)} reversals per flight (${fl.flights} flights)`);
  }
  return parts.length ? parts.join("; ") : "not recorded (periods stored before usage was)";
}

async function loadUnit(name) {
  selected = name;
  if (fleet) renderTable();
  const box = $("unit");
  try {
    const unit = await getJSON("/api/unit?name=" + encodeURIComponent(name));
    const row = fleet ? fleet.fleet.find((u) => u.actuator === name) : null;
    $("unit-name").textContent = unit.actuator;
    const st = $("unit-status");
    st.className = "badge " + (row ? row.status : "");
    st.textContent = row ? (STATUS_LABEL[row.status] || row.status) : "";
    $("unit-reason").textContent = row ? row.status_reason : "";
    $("unit-chart").replaceChildren(chart(unit));
    const facts = $("unit-facts");
    facts.replaceChildren();
    const fact = (k, v) => { facts.appendChild(el("dt", {}, k)); facts.appendChild(el("dd", {}, v)); };
    const obs = unit.periods.filter((p) => num(p.c_lk_ratio) !== null).length;
    fact("periods", `${unit.periods.length} (${obs} with an observable C_Lk)`);
    fact("alarm events", unit.alarms.length ? `${unit.alarms.length}, last ${unit.alarms[unit.alarms.length - 1].kind}` : "none");
    fact("baseline versions", unit.baselines.length ? unit.baselines.map((b) => b.version).join(", ") : "none");
    fact("usage", usageText(row ? row.usage : null, unit.usage));
    const rul = unit.rul || {};
    fact("RUL model", rul.model ? `${rul.model}, horizon ${rul.axis === "flights" ? `${fmt(rul.horizon, 0)} flights` : `${fmt(rul.horizon_h, 0)} h`}` : (rul.status || "not computed"));
    box.hidden = false;
    box.dataset.unit = unit.actuator;
    document.body.dataset.unitReady = unit.actuator;
    banner("");
  } catch (e) {
    box.hidden = true;
    banner(`${name}: ${e.message}`);
  }
}

function fromHash() {
  const m = /^#unit=(.+)$/.exec(location.hash);
  if (!m) return;
  let name;
  try {
    name = decodeURIComponent(m[1]);
  } catch (e) {
    banner(`the address names no unit: ${location.hash}`);
    return;
  }
  loadUnit(name);
}

async function main() {
  const refresh = Number(document.querySelector('meta[name="servowatch-refresh-s"]').content) || 0;
  $("filter").addEventListener("input", () => { if (fleet) renderTable(); });
  window.addEventListener("hashchange", fromHash);
  // one reload at a time: the next is planned when the last has ended, so a slow store
  // never piles requests up or lets an older answer overwrite a newer one
  const cycle = async () => {
    await loadFleet();
    if (refresh > 0) setTimeout(cycle, refresh * 1000);
  };
  await cycle();
  fromHash();
}

main();
