// hostd status page: live updates by polling /api/status, actions through the JSON API.
// The page works without this file; the token stays in this tab's sessionStorage only.
(function () {
  "use strict";
  var KEY = "hostd-token";
  var POLL_MS = 2000;
  document.documentElement.classList.add("js");

  function token() { return sessionStorage.getItem(KEY) || ""; }
  function flash(text, bad) {
    var el = document.getElementById("flash");
    el.textContent = text;
    el.className = bad ? "bad" : "";
  }
  function fmt(seconds) {
    if (seconds === null || seconds === undefined) return "\u2013";
    seconds = Math.floor(seconds);
    var h = Math.floor(seconds / 3600), m = Math.floor(seconds % 3600 / 60), s = seconds % 60;
    var mm = (h && m < 10 ? "0" : "") + m, ss = (s < 10 ? "0" : "") + s;
    return h ? h + ":" + mm + ":" + ss : m + ":" + ss;
  }
  function setField(root, name, text) {
    var el = root.querySelector('[data-field="' + name + '"]');
    if (el && el.textContent !== String(text)) el.textContent = text;
    return el;
  }
  function points(samples) {
    if (!samples || !samples.length) return "";
    var t0 = samples[0][0], span = (samples[samples.length - 1][0] - t0) || 1, out = [];
    samples.forEach(function (s) {
      if (s[1] === null) return;
      var y = 60 - Math.min(Math.max(s[1], 0), 260) / 260 * 60;
      out.push(((s[0] - t0) / span * 300).toFixed(1) + "," + y.toFixed(1));
    });
    return out.join(" ");
  }

  function update(s) {
    if (document.body.dataset.sig !== undefined && s.signature !== document.body.dataset.sig) {
      location.reload();
      return;
    }
    (s.queue || []).forEach(function (j) {
      var el = document.querySelector('[data-stage-of="' + CSS.escape(j.id) + '"]');
      if (el) el.textContent = j.stage ? ": " + j.stage : "";
    });
    s.printers.forEach(function (p) {
      var card = document.querySelector('[data-printer="' + CSS.escape(p.name) + '"]');
      if (!card) return;
      var st = setField(card, "state", p.state);
      if (st) st.className = "state state-" + p.state;
      Object.keys(p.temperatures).forEach(function (h) {
        var t = p.temperatures[h], el = card.querySelector('.temp[data-heater="' + CSS.escape(h) + '"]');
        if (!el) return;
        setField(el, "current", t.current === null ? "\u2013" : Math.round(t.current));
        setField(el, "target", t.target === null ? "\u2013" : Math.round(t.target));
      });
      if (p.history) Object.keys(p.history).forEach(function (h) {
        var line = card.querySelector('polyline[data-heater="' + CSS.escape(h) + '"]');
        if (line) line.setAttribute("points", points(p.history[h]));
      });
      var j = p.job;
      if (!j) return;
      var bar = card.querySelector('[data-field="progress"]');
      if (bar) bar.value = j.progress || 0;
      setField(card, "percent", (100 * (j.progress || 0)).toFixed(1));
      setField(card, "layer", j.layer || "\u2013");
      setField(card, "layers", j.layers || "\u2013");
      setField(card, "elapsed", fmt(j.elapsed_s));
      setField(card, "eta", fmt(j.eta_s));
    });
  }

  function poll() {
    fetch("/api/status?history=1", {cache: "no-store"})
      .then(function (r) { return r.json(); })
      .then(update)
      .catch(function () { flash("hostd is not answering; retrying", true); })
      .finally(function () { setTimeout(poll, POLL_MS); });
  }

  function act(form, ev) {
    ev.preventDefault();
    if (form.dataset.confirm && !window.confirm(form.dataset.confirm)) return;
    var tok = token();
    if (!tok) {
      tok = window.prompt("This node's token (kept for this tab only):") || "";
      if (!tok) return;
      sessionStorage.setItem(KEY, tok);
      showToken();
    }
    var url = form.dataset.api, opts = {method: "POST", headers: {"Authorization": "Bearer " + tok}};
    if (form.classList.contains("upload")) {
      var data = new FormData(form);
      data.delete("token");
      opts.body = data;
    } else if (url.indexOf("?to=") >= 0) {
      var to = url.split("?to=")[1];
      url = url.split("?")[0];
      opts.headers["Content-Type"] = "application/json";
      opts.body = JSON.stringify({to: to});
    }
    flash("sending\u2026");
    fetch(url, opts).then(function (r) {
      return r.json().then(function (body) {
        if (r.status === 401) sessionStorage.removeItem(KEY), showToken();
        flash(body.error || body.result || body.message || r.statusText, !r.ok);
      });
    }).catch(function (e) { flash("failed: " + e, true); });
  }

  function showToken() {
    var st = document.getElementById("token-state");
    if (st) st.textContent = token() ? "token kept for this tab" : "no token yet";
  }

  document.addEventListener("DOMContentLoaded", function () {
    var box = document.getElementById("token-box");
    if (box) {
      box.hidden = false;
      box.addEventListener("submit", function (ev) {
        ev.preventDefault();
        var input = document.getElementById("token-input");
        if (input.value) sessionStorage.setItem(KEY, input.value);
        input.value = "";
        showToken();
      });
      showToken();
    }
    document.querySelectorAll("form.action").forEach(function (f) {
      f.addEventListener("submit", function (ev) { act(f, ev); });
    });
    if (document.body.dataset.page === "node") poll();
    if (document.body.dataset.page === "farm") setInterval(function () { location.reload(); }, 10000);
  });
})();
