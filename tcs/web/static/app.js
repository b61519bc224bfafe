// tcs status page: reads /events (server-sent events, one JSON snapshot per event) and shows
// it. Read-only: it never sends anything but GETs. Plain JS, no framework, no build step.
"use strict";

const $ = (id) => document.getElementById(id);

function fmt(v, digits = 4, unit = "") {
  if (v === null || v === undefined || Number.isNaN(v)) return "unknown";
  return v.toFixed(digits) + unit;
}

function iso(t) {
  if (t === null || t === undefined) return "–";
  return new Date(t * 1000).toISOString().replace("T", " ").replace("Z", "");
}

function setText(el, text, cls) {
  if (el.textContent !== text) el.textContent = text;
  if (cls !== undefined) el.className = cls;
}

function onOff(v) {
  if (v === null || v === undefined) return ["unknown", "unknown"];
  if (v >= 1) return ["on", "ok"];
  if (v <= 0) return ["off", "muted"];
  return [Math.round(v * 100) + " %", "warn"];
}

function yesNo(v) {
  if (v === null || v === undefined) return ["unknown", "unknown"];
  return v >= 1 ? ["yes", "ok"] : (v <= 0 ? ["no", "warn"] : [Math.round(v * 100) + " %", "warn"]);
}

function row(tbody, key, cells) {
  let tr = tbody.querySelector(`tr[data-key="${CSS.escape(key)}"]`);
  if (!tr) {
    tr = document.createElement("tr");
    tr.dataset.key = key;
    for (let i = 0; i < cells.length; i++) tr.appendChild(document.createElement("td"));
    tbody.appendChild(tr);
  }
  cells.forEach((c, i) => {
    const td = tr.children[i];
    if (typeof c === "string") { setText(td, c); td.className = ""; }
    else { setText(td, c.text, c.cls || ""); if (c.html !== undefined && td.innerHTML !== c.html) td.innerHTML = c.html; }
  });
  return tr;
}

function prune(tbody, keys) {
  for (const tr of [...tbody.children]) if (!keys.has(tr.dataset.key)) tr.remove();
}

function list(ul, items) {
  const text = items.map((i) => i.text).join("\n");
  if (ul.dataset.text === text) return;
  ul.dataset.text = text;
  ul.replaceChildren(...items.map((i) => {
    const li = document.createElement("li");
    li.textContent = i.text;
    if (i.cls) li.className = i.cls;
    return li;
  }));
}

function followBar(axis) {
  // the following error on a ±10″ scale (angular axes), the bar's centre is 0
  const e = axis.following_error_arcsec;
  if (e === null || e === undefined) return { text: "–", cls: "unknown" };
  const scale = 10, w = Math.min(1, Math.abs(e) / scale) * 50;
  const left = e >= 0 ? 50 : 50 - w;
  const cls = Math.abs(e) > scale ? "bad" : (Math.abs(e) > 1 ? "warn" : "");
  return {
    text: "", cls: "fe",
    html: `<span class="bar ${cls}"><span style="left:${left}%;width:${Math.max(w, 0.5)}%"></span></span>` +
          `<span class="mono">${e.toFixed(2)}″</span>`,
  };
}

// What an axis's state means, in words and a colour that says so: tracking on target is
// good, a slew is information, off is neither, a fault is bad, no readback is unknown.
function axisState(a) {
  if (a.fault) return ["fault: " + a.fault, "bad"];
  if (!a.fresh) return ["no readback", "unknown"];
  const m = a.motion_state || 0;
  const unref = a.referenced !== null && a.referenced < 1;
  if (a.power === 0) return ["off" + (unref ? ", not referenced" : ""), "off"];
  if (unref) return [(m & 1 ? "referencing" : "not referenced"), "warn"];
  if (m & 16) return [a.motion + " (at a limit)", "warn"];
  if (m & 2 && m & 8) return ["tracking, on target", "ok"];
  if (m & 2) return ["tracking, converging", "info"];
  if (m & 1) return ["moving", "info"];
  return [a.motion === "on target" ? "at rest, on target" : "at rest", "ok"];
}

function axes(snap) {
  const tbody = $("axes").tBodies[0], keys = new Set();
  for (const a of snap.axes) {
    keys.add(a.name);
    const digits = a.unit === "deg" ? 4 : 3;
    const unit = a.unit === "deg" ? "°" : (a.unit === "mm" ? " mm" : "");
    const [state, cls] = axisState(a);
    const tr = row(tbody, a.name, [
      a.name,
      { text: fmt(a.position, digits, unit), cls: "num pos" },
      { text: fmt(a.target, digits, unit), cls: "num target" },
      { text: state, cls: "state " + cls },
      a.unit === "deg" ? followBar(a) : { text: fmt(a.following_error, 4, unit), cls: "num" },
    ]);
    tr.dataset.axis = a.name;
  }
  prune(tbody, keys);
}

function project(az, alt) {
  // azimuth from north through east, zenith in the middle, horizon on the rim (north up)
  const r = (90 - alt) / 90 * 100, a = az * Math.PI / 180;
  return [r * Math.sin(a), -r * Math.cos(a)];
}

// A small circle of radius r (degrees) around (az, alt) on the sphere, as alt-az points;
// the parts below the horizon are drawn on the rim.
function smallCircle(az, alt, r) {
  const d2r = Math.PI / 180, out = [];
  const a0 = az * d2r, h0 = alt * d2r, rr = r * d2r;
  for (let k = 0; k <= 72; k++) {
    const b = k * 5 * d2r;  // bearing from north
    const h = Math.asin(Math.sin(h0) * Math.cos(rr) + Math.cos(h0) * Math.sin(rr) * Math.cos(b));
    const a = a0 + Math.atan2(Math.sin(b) * Math.sin(rr) * Math.cos(h0), Math.cos(rr) - Math.sin(h0) * Math.sin(h));
    out.push([a / d2r, Math.max(h / d2r, -8)]);
  }
  return out;
}

function sky(snap) {
  const t = snap.tracking;
  const scope = $("scope-mark"), target = $("target-mark"), horizon = $("horizon");
  if (snap.horizon && !horizon.dataset.done) {
    const inner = snap.horizon.map(([az, alt]) => project(az, alt).map((v) => v.toFixed(1)).join(",")).join(" ");
    horizon.setAttribute("points", inner);
    horizon.dataset.done = "1";
  }
  const sun = snap.sun, mark = $("sun-mark"), cone = $("sun-cone");
  if (sun && sun.az !== null && sun.alt !== null && sun.alt + (sun.cone || 0) > -8) {
    if (sun.alt > -8) {
      const [x, y] = project(sun.az, Math.max(sun.alt, -8));
      mark.setAttribute("cx", x.toFixed(2)); mark.setAttribute("cy", y.toFixed(2));
      mark.setAttribute("visibility", "visible");
    } else mark.setAttribute("visibility", "hidden");
    if (sun.cone) {
      cone.setAttribute("points", smallCircle(sun.az, sun.alt, sun.cone)
        .map(([az, alt]) => project(az, alt).map((v) => v.toFixed(1)).join(",")).join(" "));
      cone.setAttribute("visibility", "visible");
    } else cone.setAttribute("visibility", "hidden");
  } else { mark.setAttribute("visibility", "hidden"); cone.setAttribute("visibility", "hidden"); }
  const cur = t && t.current, tgt = t && t.target;
  if (cur && cur.az !== null && cur.alt !== null) {
    const [x, y] = project(cur.az, cur.alt);
    scope.setAttribute("cx", x.toFixed(2)); scope.setAttribute("cy", y.toFixed(2));
    scope.setAttribute("visibility", "visible");
  } else scope.setAttribute("visibility", "hidden");
  if (tgt && tgt.az !== null && tgt.alt !== null && tgt.alt > -10) {
    const [x, y] = project(tgt.az, Math.max(tgt.alt, 0));
    target.setAttribute("transform", `translate(${x.toFixed(2)},${y.toFixed(2)})`);
    target.setAttribute("visibility", "visible");
  } else target.setAttribute("visibility", "hidden");
}

function radec(p) {
  if (!p || p.ra === null || p.dec === null) return "–";
  return `${p.ra.toFixed(5)} h  ${p.dec >= 0 ? "+" : ""}${p.dec.toFixed(4)}°`;
}

function tracking(snap) {
  const t = snap.tracking;
  if (!t) { $("tracking-card").hidden = true; return; }
  setText($("track"), t.tracking ? `yes (TRACK=${t.track})` : "no", t.tracking ? "ok" : "muted");
  setText($("on-target"), t.on_target === null ? "–" : (t.on_target ? "yes" : "no"),
          t.on_target ? "ok" : "muted");
  // the tracking error means something only while tracking on target; during a slew it is
  // the distance still to go, which the target distance below shows
  setText($("track-error"), t.on_target && t.distance_arcsec !== null ? t.distance_arcsec.toFixed(2) + "″"
          : (t.tracking ? "– (slewing)" : "–"), t.on_target ? "" : "muted");
  const sun = snap.sun;
  if (!sun || sun.alt === null) setText($("sun"), "–", "muted");
  else if (sun.alt < -0.83) setText($("sun"), `below the horizon (${sun.alt.toFixed(1)}°)`, "muted");
  else setText($("sun"), (sun.distance === null ? `${sun.alt.toFixed(1)}° high` : `${sun.distance.toFixed(1)}° away`)
               + (sun.cone ? ` (cone ${sun.cone}°)` : " (avoidance off)"), sun.cone ? sunClass(sun) : "warn");
  setText($("target-distance"), t.target_distance === null ? "–" : fmt(t.target_distance, 4, "°"));
  setText($("target-radec"), radec(t.target));
  setText($("current-radec"), radec(t.current));
  sky(snap);
}

function sunClass(sun) {
  if (!sun || sun.distance === null || sun.alt === null || sun.alt < -0.83 || !sun.cone) return "";
  return sun.distance < sun.cone ? "bad" : (sun.distance < sun.cone + 10 ? "warn" : "ok");
}

function enclosure(snap) {
  const tbody = $("enclosure").tBodies[0], keys = new Set();
  for (const m of [...snap.dome, ...snap.covers]) {
    keys.add(m.name);
    const state = m.closing ? "closing (weather)" : m.state;
    const cls = m.error_state & 3 ? "bad" : (!m.fresh ? "unknown" : (m.motion_state & 1 ? "info" : ""));
    row(tbody, m.name, [m.label ? `${m.name} ${m.label}` : m.name, { text: state, cls: "state " + cls }]);
  }
  prune(tbody, keys);
  $("enclosure-card").hidden = keys.size === 0 && !snap.interlock;
  const il = snap.interlock;
  setText($("interlock"), il ? (il.active ? "Weather interlock ACTIVE: " + il.reason : "Weather interlock: clear") : "",
          il && il.active ? "bad" : "muted");
}

function points(tbody, items) {
  const keys = new Set();
  for (const s of items) {
    keys.add(s.name);
    row(tbody, s.name, [s.label || s.name, { text: s.value === null ? "unknown" : String(+s.value.toFixed(3)), cls: "num" },
      s.unit || ""]);
  }
  prune(tbody, keys);
}

function links(snap) {
  const tbody = $("links").tBodies[0], keys = new Set();
  for (const p of snap.plcs) {
    keys.add("plc " + p.name);
    row(tbody, "plc " + p.name, ["PLC " + p.name, { text: p.connected ? "up" : "down", cls: p.connected ? "ok" : "bad" },
      { text: p.round_trip === null ? "" : (p.round_trip * 1000).toFixed(1) + " ms", cls: "num" }]);
  }
  if (snap.gps) {
    keys.add("gps");
    const g = snap.gps;
    const sats = g.satellites === null || g.satellites === undefined ? "" : `, ${g.satellites} sat.`;
    row(tbody, "gps", ["GPS", { text: !g.data ? "no data" : g.position_good ? `fix ${g.fix_quality} ${g.quality_name}${sats}`
                                      : `no fix (${g.quality_name})${sats}`,
                                cls: !g.data ? "bad" : g.position_good ? "ok" : "warn" },
      { text: g.time_offset === null ? "time loose" : (g.time_offset * 1000).toFixed(1) + " ms",
        cls: "num " + (g.time_offset !== null && !g.time_good ? "bad" : "") }]);
    keys.add("gps detail");
    row(tbody, "gps detail", ["", { text: g.summary || "", cls: "muted" },
      { text: (g.constellations || []).map((k) => `${k.talker} ${k.used ?? "-"}/${k.in_view ?? "-"}`).join(" "), cls: "muted" }]);
  }
  prune(tbody, keys);
}

// ERROR_STATE (OpenTCI §4): bit 0 panic, 1 error, 2 warning, 3 info, 4 debug
function errorState(v) {
  if (!v) return ["0 (none)", "ok"];
  const names = ["panic", "error", "warning", "info", "debug"].filter((_, i) => v & (1 << i));
  return [`${v} (${names.join(", ")})`, v & 3 ? "bad" : (v & 4 ? "warn" : "muted")];
}

// missed cycles are counted since start: only new ones (the last minute) are a warning
const missedSeen = [];
function loopText(l) {
  if (!l.running) return ["not running", "bad"];
  const now = Date.now(), missed = l.missed ?? 0;
  missedSeen.push([now, missed]);
  while (missedSeen.length && missedSeen[0][0] < now - 60000) missedSeen.shift();
  const recent = missed - missedSeen[0][1];
  const every = l.sync_interval && l.sync_interval !== l.period ? ` (${(l.sync_interval * 1000).toFixed(0)} ms at rest)` : "";
  return [`${(l.period * 1000).toFixed(0)} ms${every}, ${recent} missed in the last minute, ${missed} since start`,
          recent > 0 ? "warn" : "ok"];
}

function headlineCard(snap) {
  const h = snap.headline || { text: "–", level: "off", remedy: "", warnings: [] };
  setText($("headline"), h.text);
  setText($("remedy"), h.remedy || "");
  $("headline-card").className = "card wide headline " + h.level;
  document.body.dataset.state = h.state;
  list($("warnings"), (h.warnings || []).map((w) => ({ text: "warning: " + w })));
  // safety at a glance: the Sun, the weather interlock, limits, links
  const chips = [];
  const sun = snap.sun;
  if (sun && sun.alt !== null) {
    if (sun.alt < -0.83) chips.push(["Sun below the horizon", "ok"]);
    else chips.push([(sun.distance === null ? `Sun ${sun.alt.toFixed(0)}° high` : `Sun ${sun.distance.toFixed(1)}° away`)
                     + (sun.cone ? ` (cone ${sun.cone}°)` : " (Sun avoidance OFF)"), sun.cone ? (sunClass(sun) || "ok") : "warn"]);
  }
  const il = snap.interlock;
  if (il) chips.push([il.active ? "weather interlock: " + il.reason : "weather: clear", il.active ? "warn" : "ok"]);
  const limited = snap.axes.filter((a) => a.motion_state & 16).map((a) => a.name);
  chips.push([limited.length ? "at a limit: " + limited.join(", ") : "limits: clear", limited.length ? "warn" : "ok"]);
  const down = snap.plcs.filter((p) => !p.connected).map((p) => p.name);
  if (snap.plcs.length) chips.push([down.length ? "PLC lost: " + down.join(", ") : "PLCs: up", down.length ? "bad" : "ok"]);
  const box = $("safety"), text = chips.map((c) => c.join("|")).join(";");
  if (box.dataset.text !== text) {
    box.dataset.text = text;
    box.replaceChildren(...chips.map(([t, cls]) => {
      const span = document.createElement("span");
      span.className = "chip " + cls; span.textContent = t; return span;
    }));
  }
}

function render(snap) {
  setText($("config"), snap.build.config + " · " + snap.build.version);
  headlineCard(snap);
  const c = snap.cabinet;
  const [p, pc] = onOff(c.power); setText($("power"), p, pc === "muted" ? "off" : pc);
  const [r, rc] = yesNo(c.referenced); setText($("referenced"), r, rc);
  const [es, esc] = errorState(c.error_state); setText($("error-state"), es, esc);
  setText($("utc"), iso(snap.time.utc));
  setText($("tai"), iso(snap.time.tai));
  setText($("sync-utc"), iso(snap.sync.utc));
  const l = snap.loop;
  const [lt, lc] = loopText(l); setText($("loop"), lt, lc);
  const bus = snap.can;
  setText($("can"), !bus ? "–" : `${bus.state}${bus.load == null ? "" : `, load ${(bus.load * 100).toFixed(0)} %`}` +
          `${bus.error_frames ? `, ${bus.error_frames} error frames` : ""}`, !bus ? "muted" : bus.state === "ok" ? "ok" : "bad");
  setText($("seq"), String(snap.seq));
  axes(snap);
  tracking(snap);
  enclosure(snap);
  points($("sensors").tBodies[0], snap.sensors);
  points($("switches").tBodies[0], snap.switches);
  $("weather-card").hidden = !snap.sensors.length && !snap.switches.length;
  links(snap);
  $("links-card").hidden = !snap.plcs.length && !snap.gps;
  const severity = (e) => (e.bits & 3 ? "bad" : (e.bits & 4 ? "warn" : "muted"));
  const errs = [...c.errors].sort((a, b) => (b.active - a.active) || (b.last - a.last));
  list($("errors"), errs.length ? errs.map((e) => ({
    text: `${e.active ? "ACTIVE " : ""}${e.device}: ${e.error} (${e.total}×, last ${iso(e.last)})`,
    cls: e.active ? severity(e) : "muted" })) : [{ text: "none", cls: "muted" }]);
  const alpaca = (snap.front_ends || {}).alpaca;
  const rows = snap.clients.map((s) => ({ text: `${s.front_end} #${s.id} ${s.user || "(not logged in)"} from ${s.address}` }));
  if (alpaca && alpaca.connections) rows.push({ text: `alpaca: ${alpaca.connections} HTTP connection${alpaca.connections > 1 ? "s" : ""}` });
  list($("clients"), rows.length ? rows : [{ text: "none", cls: "muted" }]);
  document.body.dataset.seq = snap.seq;
}

function connect() {
  const link = $("link");
  const source = new EventSource("events");
  source.addEventListener("snapshot", (ev) => {
    try { render(JSON.parse(ev.data)); setText(link, "live", "pill ok"); }
    catch (e) { setText(link, "bad data", "pill bad"); console.error(e); }
  });
  source.onerror = () => setText(link, "reconnecting…", "pill bad");  // EventSource retries by itself
}

connect();
