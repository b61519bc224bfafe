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

function axes(snap) {
  const tbody = $("axes").tBodies[0], keys = new Set();
  for (const a of snap.axes) {
    keys.add(a.name);
    const digits = a.unit === "deg" ? 4 : 3;
    const unit = a.unit === "deg" ? "°" : (a.unit === "mm" ? " mm" : "");
    let state = a.fresh ? a.motion : "stale";
    if (a.power === 0) state = "off";
    if (a.referenced !== null && a.referenced < 1 && a.fresh) state += ", unreferenced";
    const cls = a.fault ? "bad" : (!a.fresh ? "unknown" : (a.motion_state & 1 ? "warn" : "ok"));
    const tr = row(tbody, a.name, [
      a.name,
      { text: fmt(a.position, digits, unit), cls: "num pos" },
      { text: fmt(a.target, digits, unit), cls: "num target" },
      { text: a.fault ? "fault: " + a.fault : state, cls: "state " + cls },
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

function sky(snap) {
  const t = snap.tracking;
  const scope = $("scope-mark"), target = $("target-mark"), horizon = $("horizon");
  if (snap.horizon && !horizon.dataset.done) {
    const inner = snap.horizon.map(([az, alt]) => project(az, alt).map((v) => v.toFixed(1)).join(",")).join(" ");
    horizon.setAttribute("points", inner);
    horizon.dataset.done = "1";
  }
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
  setText($("track-error"), t.distance_arcsec === null ? "–" : t.distance_arcsec.toFixed(2) + "″");
  setText($("target-distance"), t.target_distance === null ? "–" : fmt(t.target_distance, 4, "°"));
  setText($("target-radec"), radec(t.target));
  setText($("current-radec"), radec(t.current));
  sky(snap);
}

function enclosure(snap) {
  const tbody = $("enclosure").tBodies[0], keys = new Set();
  for (const m of [...snap.dome, ...snap.covers]) {
    keys.add(m.name);
    row(tbody, m.name, [m.name, { text: fmt(m.position, 2), cls: "num" },
      { text: m.closing ? "closing (weather)" : m.motion, cls: m.error_state ? "bad" : "" }]);
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

function render(snap) {
  setText($("config"), snap.build.config + " · " + snap.build.version);
  const c = snap.cabinet;
  const [p, pc] = onOff(c.power); setText($("power"), p, pc);
  const [r, rc] = yesNo(c.referenced); setText($("referenced"), r, rc);
  setText($("error-state"), String(c.error_state), c.error_state ? "bad" : "ok");
  setText($("utc"), iso(snap.time.utc));
  setText($("tai"), iso(snap.time.tai));
  setText($("sync-utc"), iso(snap.sync.utc));
  const l = snap.loop;
  setText($("loop"), l.running ? `${(l.period * 1000).toFixed(0)} ms, ${l.missed ?? 0} missed, ${l.late ?? 0} late`
                               : "not running", l.running ? "ok" : "bad");
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
  list($("errors"), c.errors.length ? c.errors.map((e) => ({
    text: `${e.active ? "ACTIVE " : ""}${e.device}: ${e.error} (${e.total}×, last ${iso(e.last)})`,
    cls: e.active ? "bad" : "muted" })) : [{ text: "none", cls: "muted" }]);
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
