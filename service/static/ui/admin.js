// The admin page (/ui/admin): GET /admin/overview with the key the main page keeps in this
// tab's sessionStorage, refreshed every few seconds. Text only (no innerHTML): job messages
// and user names come from users.
"use strict";
(() => {
  const KEY_STORAGE = "pba.apiKey";
  const REFRESH_MS = 3000;
  const $ = (id) => document.getElementById(id);

  function headers() {
    const key = sessionStorage.getItem(KEY_STORAGE) || "";
    return key ? { "X-API-Key": key } : {};
  }

  function fill(tableId, rows) {
    const body = $(tableId).querySelector("tbody");
    body.replaceChildren(
      ...rows.map((cells) => {
        const tr = document.createElement("tr");
        for (const c of cells) {
          const td = document.createElement("td");
          td.textContent = c === null || c === undefined ? "" : String(c);
          tr.appendChild(td);
        }
        return tr;
      })
    );
  }

  const when = (t) => (t ? new Date(t).toLocaleString() : "");
  const secs = (x) => x.toFixed(1);

  async function refresh() {
    let r;
    try {
      r = await fetch("admin/overview", { headers: headers() });
    } catch (e) {
      $("admin-status").textContent = `the server does not answer (${e})`;
      return;
    }
    if (r.status === 401 || r.status === 403) {
      $("admin-status").textContent =
        "admins only: enter an admin's API key on the main page (this tab), then reload";
      return;
    }
    if (!r.ok) {
      $("admin-status").textContent = `error ${r.status}`;
      return;
    }
    const o = await r.json();
    $("admin-status").textContent = `updated ${new Date().toLocaleTimeString()}`;
    $("workers-alive").textContent = String(o.workers);
    $("queue-state").textContent = o.queue;
    fill(
      "users-table",
      o.users.map((u) => [
        u.user, u.weight, u.max_running_jobs ?? "default", u.waiting, u.running,
        u.jobs_successful, u.jobs_failed, u.jobs_dismissed, secs(u.cpu_seconds),
        secs(u.solve_seconds),
      ])
    );
    fill(
      "running-table",
      o.running.map((j) => [j.jobID, j.user, j.worker, `${j.progress}%`, when(j.started), j.message])
    );
    fill(
      "failures-table",
      o.failures.map((j) => [j.jobID, j.user, when(j.finished), j.message])
    );
  }

  refresh();
  setInterval(refresh, REFRESH_MS);
})();
