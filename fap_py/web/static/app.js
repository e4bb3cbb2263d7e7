// fap web: the page. Plain JS, no library. The stream's frames are
// {seq, node, role, frame}; frame is exactly a `fap monitor --json` line.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const KEEP = 5000;          // frames this page keeps (the server's ring holds more)
  const SHOW = 300;           // rows rendered at once
  const COLORS = ["#2456a6", "#b42318", "#1d7a46", "#b54708", "#6941c6", "#0e7490", "#c11574", "#4d5761"];

  const exported = $("fap-export");
  const state = {
    info: null, frames: [], paused: false, dropped: 0, stats: null, until: null,
    selected: null, protocols: new Set(), faults: null, faultAt: 0, clientAt: 0, clientsShown: false,
    dirty: true, exportData: null,
    token: new URLSearchParams(location.hash.slice(1)).get("token"),
  };

  function api(path, params) {
    const q = new URLSearchParams(params || {});
    if (state.token) q.set("token", state.token);
    const s = q.toString();
    return "api/" + path + (s ? "?" + s : "");
  }

  function text(el, s) { if (el.textContent !== s) el.textContent = s; }

  // -- frames ---------------------------------------------------------------
  function summary(f) {
    if (f.frame === undefined) {     // a message that is no wire frame (an MQTT source's)
      return f.event + " " + JSON.stringify(f.payload).slice(0, 160);
    }
    if (!f.ok) return "!! " + (f.error || "?");
    const skip = new Set(["event", "protocol", "t", "port", "ok", "error", "frame", "data"]);
    const parts = [];
    for (const k of Object.keys(f)) {
      if (!skip.has(k) && f[k] !== null && f[k] !== undefined) parts.push(k + "=" + f[k]);
    }
    if (f.data) parts.push("[" + f.data.length / 2 + "] " + f.data);
    return parts.join(" ");
  }

  function filtered() {
    const node = $("f-node").value.trim(), proto = $("f-proto").value, kind = $("f-kind").value;
    const search = $("f-search").value.trim().toLowerCase().replace(/\s+/g, "");
    const until = state.until;
    return state.frames.filter((e) => {
      const f = e.frame;
      if (until !== null && f.t !== null && f.t > until) return false;
      if (node && String(e.node) !== node) return false;
      if (proto && f.protocol !== proto) return false;
      if (kind && (kind === "other" ? e.role !== null : e.role !== kind)) return false;
      if (search && (f.frame || "").indexOf(search) < 0 && summary(f).toLowerCase().indexOf(search) < 0) return false;
      return true;
    });
  }

  function renderFrames() {
    const rows = filtered();
    const body = $("frames").tBodies[0];
    const part = rows.slice(-SHOW);
    const html = [];
    for (const e of part) {
      const f = e.frame;
      const cls = (f.ok ? "" : "bad") + (state.selected === e.seq ? " sel" : "");
      html.push("<tr data-seq=\"" + e.seq + "\" class=\"" + cls + "\"><td>" + e.seq + "</td><td>" +
        (f.t === null ? "-" : f.t.toFixed(6)) + "</td><td>" + (f.port === null || f.port === undefined ? "" : "p" + f.port) +
        "</td><td>" + esc(f.protocol) + "</td><td>" + esc(e.node === null ? "" : e.node) + "</td><td>" +
        (e.role || "") + "</td><td>" + esc(summary(f)) + "</td><td class=\"bytes\">" + (f.frame || "") + "</td></tr>");
    }
    body.innerHTML = html.join("");
    text($("shown"), rows.length + " of " + state.frames.length + " frames" +
      (rows.length > SHOW ? " (last " + SHOW + " shown)" : ""));
    if (!state.paused) {
      const box = body.closest(".scroll");
      box.scrollTop = box.scrollHeight;
    }
  }

  function esc(s) {
    return String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", "\"": "&quot;" }[c]));
  }

  function hexdump(hex) {
    const lines = [];
    for (let i = 0; i < hex.length; i += 32) {
      const chunk = hex.slice(i, i + 32);
      const bytes = chunk.match(/../g) || [];
      const ascii = bytes.map((b) => { const c = parseInt(b, 16); return c >= 32 && c < 127 ? String.fromCharCode(c) : "."; });
      lines.push((i / 2).toString(16).padStart(4, "0") + "  " + bytes.join(" ").padEnd(48) + " |" + ascii.join("") + "|");
    }
    return lines.join("\n");
  }

  function showDetail(seq) {
    const e = state.frames.find((x) => x.seq === seq);
    if (!e) return;
    state.selected = seq;
    $("detail").textContent = (e.frame.frame !== undefined ? hexdump(e.frame.frame) + "\n\n" : "") +
      JSON.stringify(e.frame, null, 1);
    state.dirty = true;
  }

  function addFrames(list) {
    for (const e of list) {
      state.frames.push(e);
      if (!state.protocols.has(e.frame.protocol)) {
        state.protocols.add(e.frame.protocol);
        const o = document.createElement("option");
        o.value = o.textContent = e.frame.protocol;
        $("f-proto").appendChild(o);
      }
    }
    if (state.frames.length > KEEP && !(state.info && state.info.seekable)) {
      state.frames.splice(0, state.frames.length - KEEP);
    }
    state.dirty = true;
  }

  // -- node table -----------------------------------------------------------
  function renderNodes(stats) {
    const body = $("nodes").tBodies[0];
    const html = [];
    for (const n of stats.nodes) {
      const st = n.active === null ? "-" : (n.active ? "active" : "inactive");
      const errs = Object.entries(n.errors_by_kind).map((kv) => kv[0] + " " + kv[1]).join(", ");
      html.push("<tr data-node=\"" + esc(n.node) + "\"><td>" + esc(n.node) + "</td><td class=\"last_seen\">" +
        (n.last_seen === null ? "-" : n.last_seen.toFixed(3)) + "</td><td class=\"requests\">" + n.requests +
        "</td><td class=\"replies\">" + n.replies + "</td><td class=\"p50\">" + fmt(n.reply_p50_ms) +
        "</td><td class=\"p99\">" + fmt(n.reply_p99_ms) + "</td><td class=\"errors" + (n.errors ? " bad" : "") +
        "\" title=\"" + esc(errs) + "\">" + n.errors + "</td><td class=\"timeouts" + (n.timeouts ? " bad" : "") +
        "\">" + n.timeouts + "</td><td class=\"collisions\">" + n.collisions + "</td><td class=\"state state-" + st +
        "\">" + st + (n.live ? " · live" : "") + "</td></tr>");
    }
    body.innerHTML = html.join("");
    const t = stats.totals;
    text($("counts"), t.frames + " frames, " + t.bad + " bad, " + t.collisions + " collisions");
    if (t.baud) text($("load-cap"), "(" + t.baud + " baud = " + t.baud / 10 + " B/s)");
    plots(stats.series);
  }

  function fmt(v) { return v === null || v === undefined ? "-" : v.toFixed(3); }

  // -- plots (canvas) -------------------------------------------------------
  function plot(canvas, xs, lines, opts) {
    const ctx = canvas.getContext("2d");
    const w = canvas.width, h = canvas.height, pad = 30;
    ctx.clearRect(0, 0, w, h);
    ctx.font = "10px sans-serif";
    ctx.fillStyle = "#6b7280";
    let ymax = opts.ymax || 0;
    if (!opts.ymax) for (const l of lines) for (const v of l.values) if (v !== null && v > ymax) ymax = v;
    if (!(ymax > 0)) ymax = 1;
    ctx.strokeStyle = "#e5e7eb";
    ctx.beginPath(); ctx.moveTo(pad, 4); ctx.lineTo(pad, h - 14); ctx.lineTo(w - 4, h - 14); ctx.stroke();
    ctx.fillText(opts.fmt ? opts.fmt(ymax) : String(+ymax.toPrecision(3)), 2, 10);
    ctx.fillText("0", 2, h - 14);
    if (xs.length < 1) { ctx.fillText("no data yet", w / 2 - 25, h / 2); return; }
    const x0 = xs[0], x1 = xs[xs.length - 1] > x0 ? xs[xs.length - 1] : x0 + 1;
    const digits = x1 - x0 < 1 ? 3 : 1;
    ctx.fillText(x0.toFixed(digits) + " s", pad, h - 2);
    ctx.fillText(x1.toFixed(digits) + " s", w - 60, h - 2);
    const X = (x) => pad + (x - x0) / (x1 - x0) * (w - pad - 6);
    const Y = (y) => h - 14 - Math.min(y, ymax) / ymax * (h - 22);
    lines.forEach((l) => {
      ctx.strokeStyle = l.color;
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      let pen = false;
      l.values.forEach((v, i) => {        // a bin without a value is bridged, not a gap
        if (v === null) return;
        if (pen) ctx.lineTo(X(xs[i]), Y(v)); else ctx.moveTo(X(xs[i]), Y(v));
        pen = true;
      });
      ctx.stroke();
      ctx.fillStyle = l.color;
      l.values.forEach((v, i) => { if (v !== null) ctx.fillRect(X(xs[i]) - 1, Y(v) - 1, 2, 2); });
    });
  }

  function plots(s) {
    plot($("plot-fps"), s.t, [{ values: s.fps, color: COLORS[0] }], {});
    plot($("plot-load"), s.t, [{ values: s.load, color: COLORS[2] }],
      { ymax: 1, fmt: () => "100%" });
    const nodes = Object.keys(s.reply_ms).sort((a, b) => (+a) - (+b));
    const lines = nodes.map((n, i) => ({ values: s.reply_ms[n], color: COLORS[i % COLORS.length] }));
    plot($("plot-reply"), s.t, lines, {});
    $("reply-legend").innerHTML = nodes.map((n, i) =>
      "<span><i style=\"background:" + COLORS[i % COLORS.length] + "\"></i>node " + esc(n) + "</span>").join("");
  }

  // -- faults (a simulator source) -----------------------------------------
  function loadFaults() {
    return fetch(api("faults")).then((r) => r.json()).then((a) => {
      if (!a.ok) { $("fault-error").textContent = a.error; return; }
      state.faults = a.result;
      renderFaults();
    }).catch((err) => { $("fault-error").textContent = String(err); });
  }

  function renderFaults() {
    // rows built once (a select the user is on is never redrawn); switches updated in place
    const f = state.faults;
    const body = $("fault-nodes").tBodies[0];
    const key = f.nodes.map((n) => n.address).join(",") + "|" + f.kinds.join(",");
    if (body.dataset.key !== key) {
      body.dataset.key = key;
      const opts = f.kinds.map((k) => "<option>" + esc(k) + "</option>").join("");
      body.innerHTML = f.nodes.map((n) => "<tr data-node=\"" + n.address + "\"><td>" + n.address +
        "</td><td><select>" + opts + "</select></td><td><button type=\"button\" class=\"fault-toggle\">" +
        "switch on</button></td></tr>").join("");
    }
    const active = {};
    for (const x of f.faults) active[String(x.node)] = x;
    for (const row of body.rows) {
      const on = active[row.dataset.node];
      const btn = row.querySelector("button");
      const id = on ? String(on.id) : "";
      if (btn.dataset.on !== id || btn.disabled) {
        btn.dataset.on = id;
        btn.textContent = on ? "switch off" : "switch on";
        btn.disabled = false;
        if (on) row.querySelector("select").value = on.kind;
      }
      row.className = on ? "fault-on" : "";
    }
    $("fault-list").innerHTML = f.faults.map((x) => "<li>#" + x.id + " " + esc(x.kind) + " node " + esc(x.node) +
      " p=" + x.probability + " applied " + (x.applied || 0) + "</li>").join("") || "<li>no fault in force</li>";
  }

  function toggleFault(btn) {
    const row = btn.closest("tr");
    const node = parseInt(row.dataset.node, 10);
    $("fault-error").textContent = "";
    const req = btn.dataset.on
      ? fetch(api("faults/" + btn.dataset.on), { method: "DELETE" })
      : fetch(api("faults"), { method: "POST", headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ kind: row.querySelector("select").value, node: node }) });
    btn.disabled = true;
    req.then((r) => r.json()).then((a) => {
      if (!a.ok) $("fault-error").textContent = a.error;
      return loadFaults();
    }).catch((err) => { $("fault-error").textContent = String(err); });
  }

  // -- clients (a daemon source) --------------------------------------------
  function loadClients() {
    return fetch(api("clients")).then((r) => r.json()).then((a) => {
      if (!a.ok) { $("clients-error").textContent = a.error; return; }
      $("clients-error").textContent = "";
      const st = a.result, t = st.totals || {};
      text($("clients-total"), (t.transactions || 0) + " transactions, " + (t.late || 0) + " late, " +
        (t.errors || 0) + " errors, port " + ((st.daemon && st.daemon.port_state) || "?"));
      $("client-table").tBodies[0].innerHTML = (st.clients || []).map((c) => "<tr><td>" + esc(c.name || c.client) +
        "</td><td>" + esc(c.peer || "") + "</td><td>" + c.weight + "</td><td>" + c.priority + "</td><td>" +
        c.queued + "</td><td>" + c.transactions + "</td><td>" + (100 * (c.share || 0)).toFixed(1) +
        " %</td><td" + (c.late ? " class=\"bad\"" : "") + ">" + c.late + "</td><td" +
        (c.errors ? " class=\"bad\"" : "") + ">" + c.errors + "</td></tr>").join("") ||
        "<tr><td colspan=\"9\">no client</td></tr>";
    }).catch((err) => { $("clients-error").textContent = String(err); });
  }

  // -- the capture slider ---------------------------------------------------
  let sliderTimer = null;
  function onSlider() {
    const span = state.info.span;
    if (!span) return;
    const v = +$("slider").value / 1000;
    state.until = span[0] + (span[1] - span[0]) * v;
    text($("slider-t"), (state.until - span[0]).toFixed(3) + " s of " + (span[1] - span[0]).toFixed(3) + " s");
    state.dirty = true;
    setDownloads();
    if (state.exportData) {
      const steps = state.exportData.steps;
      let best = steps[steps.length - 1];
      for (const s of steps) { if (s.until >= state.until - 1e-9) { best = s; break; } }
      if (best) renderNodes(best);
      return;
    }
    clearTimeout(sliderTimer);
    sliderTimer = setTimeout(() => {
      fetch(api("stats", { t1: state.until })).then((r) => r.json()).then((s) => {
        state.stats = s; renderNodes(s);
        $("slider").dataset.loaded = String($("slider").value);
      }).catch((err) => { text($("status"), "error " + err); });
    }, 80);
  }

  function setDownloads() {
    const p = state.until !== null ? { t1: state.until } : {};
    if (!state.until && state.frames.length && !(state.info && state.info.seekable)) {
      p.seq0 = state.frames[0].seq;     // the page's window
    }
    $("dl-pcap").href = api("download.pcap", p);
    $("dl-jsonl").href = api("download.jsonl", p);
    $("dl-html").href = api("export.html", p);
  }

  // -- the source -----------------------------------------------------------
  function onInfo(info) {
    state.info = info;
    let where = info.port || info.capture || (info.bus ? "bus " + info.bus : "");
    text($("source"), info.kind + " " + where + " · " + (info.decoding || info.protocol) +
      (info.baud ? " · " + info.baud + " baud" : ""));
    if (info.faults && !state.exportData) {
      $("faults").hidden = false;
      text($("master-port"), info.master_port ? "master port: " + info.master_port : "");
      if (!state.faults) loadFaults();
    }
    if (info.clients && !state.exportData) {
      $("clients").hidden = false;
      if (!state.clientsShown) { state.clientsShown = true; loadClients(); }
    }
    if (info.seekable) { $("slider-row").hidden = false; if (info.span) onSlider(); }
    setDownloads();
  }

  function connect() {
    const es = new EventSource(api("stream", state.info && state.info.seekable ? { backlog: 100000000 } : {}));
    es.addEventListener("info", (ev) => onInfo(JSON.parse(ev.data)));
    es.addEventListener("frames", (ev) => addFrames(JSON.parse(ev.data)));
    es.addEventListener("dropped", (ev) => {
      const d = JSON.parse(ev.data);
      state.dropped = d.total;
      const el = $("dropped");
      text(el, "dropped " + d.total);
      el.className = "pill lost";
    });
    es.addEventListener("stats", (ev) => {
      const s = JSON.parse(ev.data);
      if (s.source.done && state.info && state.info.seekable && !state.info.span) {
        fetch(api("info")).then((r) => r.json()).then(onInfo).catch(() => {});
      }
      if (state.until === null) { state.stats = s; if (!state.paused) renderNodes(s); }
      const st = $("status");
      if (s.source.error) { text(st, "source error: " + s.source.error); st.className = "pill lost"; }
      else if (s.source.done) { text(st, "ended"); st.className = "pill ended"; }
      else if (state.paused) { text(st, "paused"); st.className = "pill paused"; }
      else { text(st, "live"); st.className = "pill live"; }
      const now = Date.now();
      if (state.faults && !state.paused && now - state.faultAt >= 2000) { state.faultAt = now; loadFaults(); }
      if (state.clientsShown && !state.paused && now - state.clientAt >= 1000) { state.clientAt = now; loadClients(); }
    });
    es.onerror = () => { const st = $("status"); text(st, "reconnecting"); st.className = "pill paused"; };
  }

  function loop() {
    if (state.dirty && !state.paused) { state.dirty = false; renderFrames(); }
    requestAnimationFrame(loop);
  }

  // -- wiring ---------------------------------------------------------------
  $("pause").addEventListener("click", () => {
    state.paused = !state.paused;
    text($("pause"), state.paused ? "Resume" : "Pause");
    state.dirty = true;
  });
  for (const id of ["f-node", "f-proto", "f-kind", "f-search"]) {
    $(id).addEventListener("input", () => { state.dirty = true; if (state.paused) renderFrames(); });
  }
  $("frames").addEventListener("click", (ev) => {
    const tr = ev.target.closest("tr[data-seq]");
    if (tr) { showDetail(parseInt(tr.dataset.seq, 10)); renderFrames(); }
  });
  $("fault-nodes").addEventListener("click", (ev) => {
    const b = ev.target.closest("button.fault-toggle");
    if (b) toggleFault(b);
  });
  $("slider").addEventListener("input", onSlider);

  if (exported) {                 // a self-contained export: no server
    const data = state.exportData = JSON.parse(exported.textContent);
    for (const id of ["dl-pcap", "dl-jsonl", "dl-html"]) $(id).hidden = true;
    onInfo(data.info);
    addFrames(data.frames);
    text($("status"), "export" + (data.info.truncated ? " (" + data.info.truncated + " frames left out)" : ""));
    renderNodes(data.stats);
    if (!data.info.span && data.frames.length) {
      const ts = data.frames.map((e) => e.frame.t).filter((t) => t !== null);
      if (ts.length) { data.info.span = [Math.min.apply(null, ts), Math.max.apply(null, ts)]; }
    }
    if (data.info.span) { $("slider-row").hidden = false; onSlider(); }
  } else {
    fetch(api("info")).then((r) => r.json()).then((info) => { onInfo(info); connect(); })
      .catch((err) => { text($("status"), "no server: " + err); });
  }
  requestAnimationFrame(loop);
})();
