// Shared by the console's pages: JSON calls, the live stream, small formatting helpers.
"use strict";

const guadal = {
  async getJSON(url) {
    const r = await fetch(url, { credentials: "same-origin" });
    if (r.status === 401) { location.href = "/login?next=" + encodeURIComponent(location.pathname); throw new Error("login"); }
    if (!r.ok) throw new Error((await r.json().catch(() => ({}))).error || r.statusText);
    return r.json();
  },

  async postJSON(url, body) {
    const r = await fetch(url, {
      method: "POST", credentials: "same-origin",
      headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
    });
    const data = await r.json().catch(() => ({}));
    if (!r.ok) throw new Error(data.error || r.statusText);
    return data;
  },

  // Server-sent events: the browser reconnects by itself and resumes from the last event id.
  stream(url, handlers) {
    const link = document.getElementById("link");
    const source = new EventSource(url, { withCredentials: true });
    source.onopen = () => { if (link) { link.textContent = "connected"; link.classList.remove("down"); } };
    source.onerror = () => { if (link) { link.textContent = "reconnecting…"; link.classList.add("down"); } };
    for (const [name, fn] of Object.entries(handlers)) {
      source.addEventListener(name, (e) => fn(JSON.parse(e.data)));
    }
    return source;
  },

  async showUser() {
    const me = await guadal.getJSON("/api/me");
    const el = document.getElementById("who");
    if (!el) return me;
    if (me.user) {
      el.innerHTML = "";
      const form = document.createElement("form");
      form.method = "post"; form.action = "/logout"; form.style.display = "inline";
      form.innerHTML = `logged in as <b>${guadal.esc(me.user)}</b> <button type="submit">log out</button>`;
      el.appendChild(form);
    } else if (me.login_available) {
      el.innerHTML = `<a href="/login?next=${encodeURIComponent(location.pathname)}">log in</a> (viewing read-only)`;
    } else {
      el.textContent = "read-only";
    }
    return me;
  },

  esc(text) {
    return String(text ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
  },

  num(value, digits = 3) {
    if (value === null || value === undefined || value === "" || Number.isNaN(Number(value))) return "–";
    const v = Number(value);
    return Math.abs(v) >= 1000 || Number.isInteger(v) ? v.toFixed(0) : v.toPrecision(digits);
  },

  when(iso) {
    if (!iso) return "";
    const d = new Date(iso);
    return Number.isNaN(d.getTime()) ? String(iso) : d.toLocaleString();
  },
};
