// Pushbroom orientation server: the web page. Plain JavaScript, no build step.
// It uses the public API only: POST /jobs/validate, POST /processes/{id}/execution (async),
// GET /jobs, GET /jobs/{id}/events (SSE), DELETE /jobs/{id}, GET /jobs/{id}/results[/*.csv],
// GET /jobs/{id}/plots[/{kind}.{png|svg}], and /ui/examples for the example documents.
// URLs are relative to <base href> (the server's base URL). Every value from the server is put
// in the page as text (never as HTML).
"use strict";

(() => {
  const KEY_STORAGE = "pba.apiKey";
  const AUTO_VALIDATE_MAX_CHARS = 1_500_000; // larger documents: validate on load / on demand
  const FINISHED = new Set(["successful", "failed", "dismissed"]);

  const $ = (id) => document.getElementById(id);
  const state = {
    current: null, // job id followed in the "current" panel
    events: null, // EventSource of the current job
    poll: null, // fallback poll timer
    validateTimer: null,
    validateSeq: 0,
    blobUrls: [],
    result: null, // {jobId, report}
    modelNames: [],
  };

  // -- small DOM helpers -----------------------------------------------------------------------
  function el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === null || v === undefined || v === false) continue;
      if (k === "class") node.className = v;
      else if (k === "text") node.textContent = v;
      else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
      else if (k === "dataset") Object.assign(node.dataset, v);
      else node.setAttribute(k, v === true ? "" : String(v));
    }
    for (const c of children.flat()) {
      if (c === null || c === undefined || c === false) continue;
      node.append(c instanceof Node ? c : document.createTextNode(String(c)));
    }
    return node;
  }
  const clear = (node) => { while (node.firstChild) node.removeChild(node.firstChild); return node; };

  function fmtNum(v, digits = 3) {
    if (v === null || v === undefined || Number.isNaN(v)) return "–";
    if (typeof v !== "number") return String(v);
    const a = Math.abs(v);
    if (a !== 0 && (a >= 1e7 || a < 1e-4)) return v.toExponential(digits);
    return v.toFixed(digits);
  }
  function fmtSig(v, sig = 2) {
    if (v === null || v === undefined || Number.isNaN(v)) return "–";
    const a = Math.abs(v);
    if (a !== 0 && (a >= 1e7 || a < 1e-4)) return v.toExponential(sig - 1);
    return Number(v.toPrecision(sig)).toString();
  }
  // a value with as many decimals as its sigma warrants (two significant digits of sigma)
  function fmtValue(value, sigma) {
    if (value === null || value === undefined) return "–";
    if (sigma && sigma > 0 && Number.isFinite(sigma)) {
      if (sigma < 1e-4 && Math.abs(value) < 1e-3) {
        // tiny polynomial coefficients: as many mantissa digits as sigma warrants
        const digits = Math.max(1, Math.min(8, Math.floor(Math.log10(Math.abs(value) || sigma)) - Math.floor(Math.log10(sigma)) + 1));
        return value.toExponential(digits);
      }
      const decimals = Math.min(10, Math.max(0, 1 - Math.floor(Math.log10(sigma))));
      return value.toFixed(decimals);
    }
    return Number(value.toPrecision(8)).toString();
  }
  function fmtTime(iso) {
    if (!iso) return "";
    const d = new Date(iso);
    if (Number.isNaN(d.getTime())) return iso;
    const p2 = (n) => String(n).padStart(2, "0");
    const day = `${d.getFullYear()}-${p2(d.getMonth() + 1)}-${p2(d.getDate())}`;
    const time = `${p2(d.getHours())}:${p2(d.getMinutes())}:${p2(d.getSeconds())}`;
    return new Date().toDateString() === d.toDateString() ? time : `${day} ${time}`;
  }
  const fmtBytes = (n) => (n > 1e6 ? `${(n / 1e6).toFixed(1)} MB` : `${Math.max(1, Math.round(n / 1e3))} kB`);
  const badge = (status) => el("span", { class: `badge ${status}`, text: status });
  const verdict = (passed, yes, no) =>
    passed === null || passed === undefined
      ? el("span", { class: "muted", text: "–" })
      : el("span", { class: `badge ${passed ? "pass" : "fail"}`, text: passed ? yes : no });

  // -- API ----------------------------------------------------------------------------------------
  class ApiError extends Error {
    constructor(status, problem) {
      super((problem && (problem.detail || problem.title)) || `HTTP ${status}`);
      this.status = status;
      this.problem = problem || {};
    }
  }
  const apiKey = () => sessionStorage.getItem(KEY_STORAGE) || "";

  async function api(path, { method = "GET", body, headers = {}, as = "json" } = {}) {
    const h = { Accept: as === "json" ? "application/json" : "*/*", ...headers };
    const key = apiKey();
    if (key) h["X-API-Key"] = key;
    if (body !== undefined) h["Content-Type"] = "application/json";
    const r = await fetch(path, { method, headers: h, body });
    if (!r.ok) {
      let problem = null;
      try { problem = await r.json(); } catch (e) { problem = null; }
      if (r.status === 401) showKeyStatus(problem && problem.detail ? problem.detail : "API key required", true);
      throw new ApiError(r.status, problem);
    }
    if (as === "blob") return r.blob();
    if (as === "text") return r.text();
    if (as === "response") return r;
    return r.json();
  }

  // -- API key -----------------------------------------------------------------------------------
  function showKeyStatus(text, bad) {
    const s = $("key-status");
    s.textContent = text;
    s.classList.toggle("bad", !!bad);
  }
  function initKey() {
    const input = $("api-key");
    input.value = apiKey();
    showKeyStatus(apiKey() ? "key in use (this tab)" : "no key: local mode");
    $("key-form").addEventListener("submit", (ev) => {
      ev.preventDefault();
      const v = input.value.trim();
      if (v) sessionStorage.setItem(KEY_STORAGE, v); else sessionStorage.removeItem(KEY_STORAGE);
      showKeyStatus(v ? "key in use (this tab)" : "no key: local mode");
      refreshJobs();
      if (state.current) openJob(state.current);
    });
    $("key-forget").addEventListener("click", () => {
      sessionStorage.removeItem(KEY_STORAGE);
      input.value = "";
      showKeyStatus("no key: local mode");
      refreshJobs();
    });
  }

  // -- job document input ---------------------------------------------------------------------------
  async function initExamples() {
    const select = $("example");
    try {
      const { examples } = await api("ui/examples");
      for (const ex of examples) {
        const counts = ex.observations ? `, ${ex.images} images, ${ex.observations} observations` : "";
        select.append(el("option", { value: ex.name, text: `${ex.title} (${ex.name}${counts})` }));
      }
      if (!examples.length) select.append(el("option", { value: "", disabled: true, text: "no examples on this server" }));
    } catch (e) {
      select.append(el("option", { value: "", disabled: true, text: "examples unavailable" }));
    }
    select.addEventListener("change", async () => {
      if (!select.value) return;
      try {
        const text = await api(`ui/examples/${encodeURIComponent(select.value)}`, { as: "text" });
        setDocument(text, `example ${select.value}`);
      } catch (e) {
        showValidation("bad", el("p", { text: `Could not load the example: ${e.message}` }));
      }
    });
  }

  async function initModels() {
    try {
      const desc = await api("processes/model-comparison");
      const items = desc.inputs && desc.inputs.models && desc.inputs.models.schema && desc.inputs.models.schema.items;
      state.modelNames = (items && items.enum) || [];
      if (state.modelNames.length) $("models").title = `available: ${state.modelNames.join(", ")}`;
    } catch (e) { /* the field still works, the server validates */ }
  }

  function setDocument(text, origin) {
    const ta = $("job-text");
    if (text.length <= AUTO_VALIDATE_MAX_CHARS) {
      // pretty-print small documents so they can be read and edited
      try { text = JSON.stringify(JSON.parse(text), null, 2); } catch (e) { /* shown by validate */ }
    }
    ta.value = text;
    $("doc-info").textContent = `${origin}: ${fmtBytes(text.length)}`;
    scheduleValidate(0);
  }

  function initInput() {
    const ta = $("job-text");
    $("process").addEventListener("change", () => {
      $("models-box").hidden = $("process").value !== "model-comparison";
      scheduleValidate(0);
    });
    $("models").addEventListener("input", () => scheduleValidate());
    $("file").addEventListener("change", () => {
      const f = $("file").files[0];
      if (f) readFile(f);
    });
    ta.addEventListener("input", () => {
      $("doc-info").textContent = ta.value ? `edited: ${fmtBytes(ta.value.length)}` : "";
      if (ta.value.length <= AUTO_VALIDATE_MAX_CHARS) scheduleValidate();
    });
    ta.addEventListener("dragover", (ev) => { ev.preventDefault(); ta.classList.add("dragover"); });
    ta.addEventListener("dragleave", () => ta.classList.remove("dragover"));
    ta.addEventListener("drop", (ev) => {
      ev.preventDefault();
      ta.classList.remove("dragover");
      const f = ev.dataTransfer && ev.dataTransfer.files[0];
      if (f) readFile(f);
    });
    $("validate").addEventListener("click", () => validate());
    $("submit").addEventListener("click", submit);
  }

  function readFile(file) {
    const reader = new FileReader();
    reader.onload = () => setDocument(String(reader.result), `file ${file.name}`);
    reader.onerror = () => showValidation("bad", el("p", { text: `Could not read ${file.name}` }));
    reader.readAsText(file);
  }

  // the execute/validate body from the editor, or an error to show
  function buildBody() {
    const text = $("job-text").value;
    if (!text.trim()) return { error: el("p", { text: "Paste, upload or pick a job document first." }) };
    let job;
    try {
      job = JSON.parse(text);
    } catch (e) {
      return { error: jsonError(text, e) };
    }
    if (job === null || typeof job !== "object" || Array.isArray(job)) {
      return { error: el("p", { text: "The document must be a JSON object (a job document)." }) };
    }
    // a whole execute request pasted in is accepted too
    const inputs = job.inputs && job.inputs.job ? { ...job.inputs } : { job };
    const process = $("process").value;
    if (process === "model-comparison") {
      const models = $("models").value.split(/[\s,]+/).filter(Boolean);
      if (models.length) inputs.models = models;
    }
    return { process, body: JSON.stringify({ inputs }) };
  }

  // offset of the first syntax error of a JSON text (null if there is none); JSON.parse's own
  // messages do not always say where
  function jsonErrorOffset(text) {
    let i = 0;
    const fail = () => { throw i; };
    const ws = () => { while (i < text.length && " \t\n\r".includes(text[i])) i++; };
    const string = () => {
      i++;
      while (i < text.length) {
        const c = text[i];
        if (c === '"') { i++; return; }
        if (c === "\\") i += 2; else if (c < " ") fail(); else i++;
      }
      fail();
    };
    const value = () => {
      ws();
      const c = text[i];
      if (c === "{" || c === "[") {
        const close = c === "{" ? "}" : "]";
        i++; ws();
        if (text[i] === close) { i++; return; }
        for (;;) {
          ws();
          if (c === "{") {
            if (text[i] !== '"') fail();
            string(); ws();
            if (text[i] !== ":") fail();
            i++;
          }
          value(); ws();
          if (text[i] === ",") { i++; continue; }
          if (text[i] === close) { i++; return; }
          fail();
        }
      }
      if (c === '"') { string(); return; }
      const m = /^(-?(0|[1-9]\d*)(\.\d+)?([eE][+-]?\d+)?|true|false|null)/.exec(text.slice(i, i + 64));
      if (m) { i += m[0].length; return; }
      fail();
    };
    try {
      value(); ws();
      if (i < text.length) fail();
      return null;
    } catch (pos) {
      if (typeof pos === "number") return pos;
      throw pos;
    }
  }

  function jsonError(text, e) {
    const pos = jsonErrorOffset(text);
    const parts = [el("h4", { text: "Not valid JSON" }), el("p", { text: e.message })];
    if (pos !== null) {
      const before = text.slice(0, pos).split("\n");
      const line = before.length;
      const column = before[before.length - 1].length + 1;
      const lineText = text.split("\n")[line - 1] || "";
      const start = Math.max(0, column - 60);
      parts.push(el("p", {}, el("strong", { text: `line ${line}, column ${column}` })),
        el("pre", { class: "snippet", text: `${lineText.slice(start, start + 100)}\n${" ".repeat(column - 1 - start)}^` }));
    }
    return el("div", {}, ...parts);
  }

  function showValidation(kind, ...content) {
    const box = $("validation");
    box.className = `validation ${kind || ""}`;
    clear(box).append(...content.filter((c) => c !== null && c !== undefined));
  }

  function problemContent(err, heading) {
    const p = err.problem || {};
    const items = (p.errors || []).map((e) =>
      el("li", {}, el("code", { text: e.pointer || "/" }), " ", e.message || e.code || ""));
    return el("div", { class: "problem" },
      el("h4", { text: `${heading}: ${p.title || "error"} (${err.status})` }),
      el("p", { text: p.detail || err.message }),
      items.length ? el("ul", { class: "problems" }, items) : null);
  }

  function scheduleValidate(delay = 700) {
    clearTimeout(state.validateTimer);
    state.validateTimer = setTimeout(validate, delay);
  }

  async function validate() {
    clearTimeout(state.validateTimer);
    const built = buildBody();
    const seq = ++state.validateSeq;
    if (built.error) { showValidation("bad", built.error); return false; }
    $("validation").classList.add("busy");
    try {
      const rep = await api(`jobs/validate?process=${encodeURIComponent(built.process)}`, { method: "POST", body: built.body });
      if (seq !== state.validateSeq) return rep.valid;
      const MAX_LISTED = 8;
      const all = rep.images || [];
      const images = all.slice(0, MAX_LISTED).map((im) =>
        el("li", {}, el("code", { text: im.id }), ` ${im.model || ""}`, im.n_parameters ? `, ${im.n_parameters} parameters` : ""));
      if (all.length > MAX_LISTED) images.push(el("li", { class: "muted", text: `and ${all.length - MAX_LISTED} more images` }));
      const notes = (rep.problems || []).map((p) => el("li", { text: p.message || JSON.stringify(p) }));
      showValidation("ok",
        el("h4", { text: "Valid job" }),
        el("p", {}, rep.planned_points !== undefined
          ? `pre-analysis: ${rep.planned_points} planned points, projected into ${all.length} images when it runs`
          : `${rep.n_observations} observations, ${rep.n_unknowns} unknowns, ${rep.dof} degrees of freedom`),
        images.length ? el("ul", {}, images) : null,
        notes.length ? el("div", {}, el("h4", { text: "Notes" }), el("ul", {}, notes)) : null);
      return true;
    } catch (err) {
      if (seq !== state.validateSeq) return false;
      if (err instanceof ApiError) showValidation("bad", problemContent(err, "Not valid"));
      else showValidation("bad", el("p", { text: `Validation failed: ${err.message}` }));
      return false;
    }
  }

  async function submit() {
    const built = buildBody();
    if (built.error) { showValidation("bad", built.error); return; }
    const btn = $("submit");
    btn.disabled = true;
    try {
      const st = await api(`processes/${encodeURIComponent(built.process)}/execution`, {
        method: "POST", body: built.body, headers: { Prefer: "respond-async" },
      });
      $("cur-progress").value = 0;
      follow(st.jobID, st);
      $("current").scrollIntoView({ behavior: "smooth", block: "start" });
      refreshJobs();
    } catch (err) {
      if (err instanceof ApiError) showValidation("bad", problemContent(err, "Not submitted"));
      else showValidation("bad", el("p", { text: `Not submitted: ${err.message}` }));
    } finally {
      btn.disabled = false;
    }
  }

  // -- following a job ---------------------------------------------------------------------------
  function stopFollowing() {
    if (state.events) { state.events.close(); state.events = null; }
    if (state.poll) { clearTimeout(state.poll); state.poll = null; }
  }

  function follow(jobId, status) {
    stopFollowing();
    state.current = jobId;
    history.replaceState(null, "", `#job=${encodeURIComponent(jobId)}`);
    $("current").hidden = false;
    $("result").hidden = true;
    $("cur-id").textContent = jobId;
    if (status) showStatus(status);
    const key = apiKey();
    const url = `jobs/${encodeURIComponent(jobId)}/events${key ? `?api_key=${encodeURIComponent(key)}` : ""}`;
    const es = new EventSource(url);
    state.events = es;
    es.addEventListener("status", (ev) => {
      if (state.current !== jobId) return;
      let st;
      try { st = JSON.parse(ev.data); } catch (e) { return; }
      showStatus(st);
      if (FINISHED.has(st.status)) finished(jobId, st);
    });
    es.onerror = () => {
      // the stream ended (the server closes it after the job ends) or broke: poll instead
      if (state.events === es) { es.close(); state.events = null; }
      if (state.current === jobId && !state.finished) pollStatus(jobId);
    };
    state.finished = false;
  }

  async function pollStatus(jobId) {
    if (state.current !== jobId || state.finished) return;
    try {
      const st = await api(`jobs/${encodeURIComponent(jobId)}`);
      if (state.current !== jobId) return;
      showStatus(st);
      if (FINISHED.has(st.status)) { finished(jobId, st); return; }
    } catch (err) {
      if (state.current !== jobId) return;
      $("cur-message").textContent = `cannot read the job's status: ${err.message}`;
      if (err.status === 404 || err.status === 401) return;
    }
    state.poll = setTimeout(() => pollStatus(jobId), 1000);
  }

  function showStatus(st) {
    const st_ = $("cur-status");
    st_.className = `badge ${st.status}`;
    st_.textContent = st.status;
    $("cur-process").textContent = st.processID || "";
    const p = Math.max(Number($("cur-progress").value) || 0, st.progress || 0);
    $("cur-progress").value = st.status === "successful" ? 100 : p;
    $("cur-percent").textContent = `${st.status === "successful" ? 100 : p}%`;
    $("cur-message").textContent = st.message || "";
    $("cancel").disabled = FINISHED.has(st.status);
    $("cancel").textContent = "Cancel";
    const probs = $("cur-problems");
    clear(probs);
    if (st.status === "failed") {
      const items = (st.problems || []).map((e) => el("li", {}, el("code", { text: e.pointer || "/" }), " ", e.message || ""));
      probs.append(el("div", { class: "error-box" }, el("strong", { text: "The job failed. " }), st.message || "",
        items.length ? el("ul", {}, items) : null));
    }
    updateJobRow(st);
  }

  function finished(jobId, st) {
    if (state.finished) return;
    state.finished = true;
    stopFollowing();
    refreshJobs();
    if (st.status === "successful") loadResult(jobId);
  }

  async function cancelCurrent() {
    const id = state.current;
    if (!id) return;
    const btn = $("cancel");
    btn.disabled = true;
    btn.textContent = "Cancelling…";
    try {
      const st = await api(`jobs/${encodeURIComponent(id)}`, { method: "DELETE" });
      if (state.current === id) {
        showStatus(st);
        if (FINISHED.has(st.status)) finished(id, st);
        else { btn.disabled = true; btn.textContent = "Cancelling…"; }
      }
    } catch (err) {
      btn.disabled = false;
      btn.textContent = "Cancel";
      $("cur-message").textContent = `could not cancel: ${err.message}`;
    }
  }

  async function openJob(jobId) {
    try {
      const st = await api(`jobs/${encodeURIComponent(jobId)}`);
      $("cur-progress").value = 0;
      follow(jobId, st);
      if (FINISHED.has(st.status)) finished(jobId, st);
    } catch (err) {
      $("current").hidden = false;
      $("cur-id").textContent = jobId;
      $("cur-message").textContent = `cannot open the job: ${err.message}`;
    }
  }

  // -- job list ------------------------------------------------------------------------------------
  async function refreshJobs() {
    const tbody = $("jobs-table").querySelector("tbody");
    const note = $("jobs-note");
    try {
      const list = await api("jobs?limit=50");
      note.textContent = list.numberMatched > list.jobs.length ? `newest ${list.jobs.length} of ${list.numberMatched}` : "";
      clear(tbody);
      if (!list.jobs.length) tbody.append(el("tr", {}, el("td", { colspan: 4, class: "empty", text: "No jobs yet." })));
      for (const st of list.jobs) tbody.append(jobRow(st));
    } catch (err) {
      clear(tbody);
      note.textContent = err.status === 401 ? "Enter a valid API key to see your jobs." : `Cannot list jobs: ${err.message}`;
    }
  }

  function jobRow(st) {
    const running = !FINISHED.has(st.status);
    const row = el("tr", { dataset: { job: st.jobID }, class: st.jobID === state.current ? "selected" : null },
      el("td", { text: fmtTime(st.created), title: st.created }),
      el("td", {}, el("span", { class: "jobid", title: st.jobID, text: st.jobID.slice(0, 8) }), " ",
        el("span", { class: "muted", text: st.processID === "model-comparison" ? "comparison" : "" })),
      el("td", { class: "status-cell" }, badge(st.status), running ? el("progress", { max: 100, value: st.progress || 0 }) : null),
      el("td", { class: "actions-cell" },
        el("button", { type: "button", class: "small secondary", onclick: () => openJob(st.jobID), text: "Open" }),
        el("button", {
          type: "button", class: "small danger", text: running ? "Cancel" : "Dismiss",
          disabled: st.status === "dismissed",
          onclick: async () => {
            if (!running && !confirm("Dismiss this job and delete its results?")) return;
            try { await api(`jobs/${encodeURIComponent(st.jobID)}`, { method: "DELETE" }); } catch (e) { /* listed below */ }
            refreshJobs();
          },
        })));
    return row;
  }

  function updateJobRow(st) {
    const row = document.querySelector(`#jobs-table tr[data-job="${CSS.escape(st.jobID)}"]`);
    if (row) row.replaceWith(jobRow(st));
  }

  // -- result view ---------------------------------------------------------------------------------
  function revokeBlobs() {
    for (const u of state.blobUrls) URL.revokeObjectURL(u);
    state.blobUrls = [];
  }

  async function loadResult(jobId) {
    const box = $("result");
    revokeBlobs();
    clear(box).append(el("p", { class: "muted", text: "Loading the report…" }));
    box.hidden = false;
    try {
      const doc = await api(`jobs/${encodeURIComponent(jobId)}/results`);
      if (state.current !== jobId) return;
      state.result = { jobId, report: doc.report };
      renderResult(jobId, doc.report);
    } catch (err) {
      clear(box).append(el("div", { class: "error-box", text: `Cannot load the results: ${err.message}` }));
    }
  }

  function download(path, filename, label) {
    return el("button", {
      type: "button", class: "small secondary download", text: label, title: `download ${filename}`,
      dataset: { href: path },
      onclick: async (ev) => {
        const btn = ev.currentTarget;
        btn.disabled = true;
        try {
          const blob = await api(path, { as: "blob" });
          const url = URL.createObjectURL(blob);
          const a = el("a", { href: url, download: filename });
          document.body.append(a);
          a.click();
          a.remove();
          setTimeout(() => URL.revokeObjectURL(url), 10_000);
        } catch (err) {
          alert(`Download failed: ${err.message}`);
        } finally {
          btn.disabled = false;
        }
      },
    });
  }

  function renderResult(jobId, report) {
    const box = clear($("result"));
    const id = encodeURIComponent(jobId);
    const stem = (report.job_name || "job").replace(/[^A-Za-z0-9._-]+/g, "_").slice(0, 60);
    box.append(el("div", { class: "result-head" },
      el("h2", {}, "Result: ", report.job_name || jobId,
        el("span", { class: "badge", text: { comparison: "model comparison", preanalysis: "pre-analysis" }[report.kind] || "adjustment" })),
      el("div", { class: "downloads" }, el("span", { class: "muted", text: "Download:" }),
        download(`jobs/${id}/results`, `${stem}-report.json`, "report JSON"),
        download(`jobs/${id}/results/parameters.csv`, `${stem}-parameters.csv`, "parameters CSV"),
        download(`jobs/${id}/results/checkpoints.csv`, `${stem}-checkpoints.csv`, "check points CSV"),
        download(`jobs/${id}/results/observations.csv`, `${stem}-observations.csv`, "observations CSV"),
        report.quality && report.quality.rejected ? download(`jobs/${id}/results/rejected.csv`, `${stem}-rejected.csv`, "rejected CSV") : null)));
    if (report.kind === "comparison") renderComparison(box, jobId, report);
    else if (report.kind === "preanalysis") {
      const detail = el("div", { id: "preanalysis" });
      box.append(detail);
      renderPreanalysis(detail, report);
      const plots = el("div", { id: "plots-section" });
      box.append(plots);
      renderPlots(plots, jobId, null);
    } else {
      const detail = el("div", { id: "adjustment" });
      box.append(detail);
      renderAdjustment(detail, report);
      const plots = el("div", { id: "plots-section" });
      box.append(plots);
      renderPlots(plots, jobId, null);
      const map = el("div", { id: "map-section" });
      box.append(map);
      if (window.pbaMap) window.pbaMap.render(map, jobId, report, { api, el, download });
    }
  }

  function renderComparison(box, jobId, report) {
    const rows = report.table || [];
    const models = report.models || rows.map((r) => r.model);
    const ok = models.filter((m) => report.reports && report.reports[m] && !report.reports[m].error);
    box.append(el("h3", { text: "Models side by side" }));
    const t = el("table", { class: "data", id: "comparison-table" },
      el("thead", {}, el("tr", {}, ["model", "σ0", "χ² (critical)", "χ² test", "dof", "RMSE x (mm)", "RMSE y (mm)",
        "check E (m)", "check N (m)", "check U (m)", "planimetric (m)", "t-test E", "t-test N"]
        .map((h, i) => el("th", { class: i === 0 || i === 3 || i >= 11 ? null : "num", text: h })))),
      el("tbody", {}, models.map((m) => {
        const r = rows.find((x) => x.model === m);
        const sub = report.reports ? report.reports[m] : null;
        if (!r || (sub && sub.error)) {
          const why = sub && sub.error ? (sub.error.detail || sub.error.message || "failed") : "no result";
          return el("tr", {}, el("td", { text: m }), el("td", { colspan: 12, class: "muted", text: `failed: ${why}` }));
        }
        return el("tr", {},
          el("td", {}, el("strong", { text: m })),
          el("td", { class: "num", text: fmtNum(r.sigma0, 4) }),
          el("td", { class: "num", text: `${fmtNum(r.chi2_statistic, 1)} (${fmtNum(r.chi2_critical, 1)})` }),
          el("td", {}, verdict(r.chi2_passed, "passed", "rejected")),
          el("td", { class: "num", text: r.dof }),
          el("td", { class: "num", text: fmtNum(r.rmse_x_mm, 4) }),
          el("td", { class: "num", text: fmtNum(r.rmse_y_mm, 4) }),
          el("td", { class: "num", text: fmtNum(r.check_rmse_e_m, 2) }),
          el("td", { class: "num", text: fmtNum(r.check_rmse_n_m, 2) }),
          el("td", { class: "num", text: fmtNum(r.check_rmse_u_m, 2) }),
          el("td", { class: "num", text: fmtNum(r.check_rmse_planimetric_m, 2) }),
          el("td", {}, verdict(r.t_test_e_passed, "no bias", "biased")),
          el("td", {}, verdict(r.t_test_n_passed, "no bias", "biased")));
      })));
    box.append(el("div", { class: "table-wrap" }, t));
    if (!ok.length) { box.append(el("p", { class: "error-box", text: "No model produced a report." })); return; }
    const select = el("select", { id: "model-select" }, ok.map((m) => el("option", { value: m, text: m })));
    const detail = el("div", { id: "adjustment" });
    const plots = el("div", { id: "plots-section" });
    box.append(el("div", { class: "plots-bar model-bar" }, el("label", {}, "Details of model", select)), detail, plots);
    const show = () => {
      revokeBlobs();
      renderAdjustment(detail, report.reports[select.value]);
      renderPlots(plots, jobId, select.value);
    };
    select.addEventListener("change", show);
    show();
  }

  function renderAdjustment(box, report) {
    clear(box);
    const adj = report.adjustment || {};
    const chi2 = adj.chi2 || {};
    const stat = (label, value, detail, extra) => el("div", { class: "stat" },
      el("div", { class: "label", text: label }), el("div", { class: "value" }, value), detail ? el("div", { class: "detail" }, detail) : null, extra || null);
    box.append(el("h3", { text: "Adjustment" }));
    box.append(el("div", { class: "summary", id: "summary" },
      stat("σ0 a posteriori", fmtNum(adj.sigma0_aposteriori, 4), `a priori ${fmtNum(adj.sigma0_apriori, 3)}`),
      stat("χ² test of σ0²", verdict(chi2.passed, "passed", "rejected"),
        `χ² = ${fmtNum(chi2.statistic, 2)}, accepted ${fmtNum(chi2.critical_lower, 1)} – ${fmtNum(chi2.critical, 1)} (α ${chi2.alpha ?? "–"})`),
      stat("Degrees of freedom", String(adj.dof ?? "–"), `${adj.n_observations ?? "–"} observations, ${adj.n_unknowns ?? "–"} unknowns`),
      stat("Iterations", String(adj.iterations ?? "–"), `${adj.converged ? "converged" : "not converged"}: ${adj.termination || ""}`),
      stat("Solve time", `${fmtNum(adj.solve_time_s, 2)} s`, `cost ${fmtSig(adj.initial_cost, 3)} → ${fmtSig(adj.final_cost, 4)}`)));
    if (report.warnings && report.warnings.length) {
      box.append(el("div", { class: "warnings" }, el("strong", { text: "Warnings" }), el("ul", {}, report.warnings.map((w) => el("li", { text: w })))));
    }
    renderParameters(box, report);
    renderParameterAnalysis(box, report);
    renderAttitude(box, report);
    renderCheckpoints(box, report);
    renderSnooping(box, report);
    renderLeaveOneOut(box, report);
    renderParsimony(box, report);
  }

  // Data snooping (options.blunder_detection, docs/quality.md): the rejected observations and
  // the groups whose members the data cannot tell apart, with the test value, its critical
  // value and the estimated error; and the control points nothing checks.
  function renderSnooping(box, report) {
    const q = report.quality;
    if (!q || !q.blunder_detection) return;
    const bd = q.blunder_detection;
    const rejected = q.rejected || [];
    const groups = q.not_identifiable || [];
    box.append(el("h3", { text: "Blunder detection" }));
    box.append(el("p", { class: "muted", text: `${bd.test === "pope" ? "Pope's tau test (σ0 estimated)" : "Baarda's data snooping (σ0 a priori)"}, α0 ${bd.alpha0}, β ${bd.beta}; ${bd.n_removed} observation(s) removed in ${bd.adjustments} adjustment(s)` }));
    const where = (r) => [r.image, r.point ?? r.line ?? r.pass ?? "", r.time_s != null ? `t ${fmtNum(r.time_s, 3)} s` : ""].filter((x) => x !== null && x !== "").join(" / ");
    // reinstated: removed, then put back because its test against the final solution passed
    const key = (r) => [r.kind, r.image, r.point, r.line, r.pass, r.time_s].join("|");
    const back = new Map((q.reinstated || []).map((r) => [key(r), r]));
    const status = (r) => {
      if (!r.reinstated && !back.has(key(r))) return r.removed ? "removed" : "kept";
      const p = (back.get(key(r)) || {}).predicted || {};
      return `reinstated (predicted w ${fmtNum(p.w, 2)} ≤ ${fmtNum(p.critical, 2)})`;
    };
    const row = (r, group) => el("tr", { class: r.removed ? "rejected" : (back.has(key(r)) ? "reinstated" : null) },
      el("td", { text: group }), el("td", { text: r.kind }), el("td", {}, el("code", { text: where(r) })),
      el("td", { class: "num", text: fmtNum(r.w, 2) }), el("td", { class: "num", text: fmtNum(r.critical, 2) }),
      el("td", { class: "num", text: (r.estimated_error || []).map((x) => fmtNum(x, 2)).join(", ") + (r.units ? ` ${r.units}` : "") }),
      el("td", { text: status(r) }));
    const grouped = new Set(groups.flatMap((g) => (g.members || []).map(key)));
    const rows = rejected.map((r) => row(r, "–"))
      .concat(groups.flatMap((g, k) => (g.members || []).map((m) => row(m, `not identifiable #${k + 1}`))))
      .concat((q.reinstated || []).filter((r) => !grouped.has(key(r))).map((r) => row(r, "–")));
    if (!rows.length) box.append(el("p", { text: "No test failed." }));
    else box.append(el("div", { class: "table-wrap" }, el("table", { class: "data compact", id: "snooping-table" },
      el("thead", {}, el("tr", {}, ["group", "kind", "observation", "w", "critical", "estimated error", ""].map((h, i) => el("th", { class: i >= 3 && i <= 5 ? "num" : null, text: h })))),
      el("tbody", {}, rows))));
    const lost = q.lost_control;
    if (lost && (lost.points || []).length) {
      const pr = lost.predicted_check_rmse_m;
      box.append(el("p", { class: "warnings", id: "lost-control",
        text: `Control points lost to the removals: ${lost.points.join(", ")}` + (pr ? `; predicted check-point RMSE (planimetric) ${fmtNum(pr.before, 3)} m before, ${fmtNum(pr.after, 3)} m after.` : ".") }));
    }
    const outliers = q.check_point_outliers || [];
    if (outliers.length) box.append(el("p", { class: "warnings", id: "check-point-outliers",
      text: `Check points whose discrepancy test fails (a blunder outside the adjustment): ${outliers.map((o) => `${o.point} (χ² ${fmtNum(o.statistic, 1)} > ${fmtNum(o.critical, 1)})`).join("; ")}` }));
    const unchecked = (q.reliability || {}).unchecked_control_points || [];
    if (unchecked.length) box.append(el("p", { class: "muted", id: "unchecked-control", text: `Control points nothing checks (redundancy ≈ 0): ${unchecked.map((u) => `${u.point} (${u.unchecked.join(", ")})`).join("; ")}` }));
  }

  // Pre-analysis (issue 15): the predicted precision of a planned layout, before measuring.
  function renderPreanalysis(box, report) {
    clear(box);
    const adj = report.adjustment || {};
    const cp = report.checkpoints || {};
    const pr = cp.predicted_rmse_m || {};
    box.append(el("h3", { text: "Pre-analysis" }));
    box.append(el("p", { class: "muted", text: `${adj.n_planned_image_points ?? "–"} planned image points, ${adj.n_unknowns ?? "–"} unknowns, ${adj.dof ?? "–"} degrees of freedom; σ0 a priori ${fmtNum(adj.sigma0_apriori, 3)}. Predicted standard deviations in the local geodetic system (m).` }));
    box.append(el("div", { class: "table-wrap" }, el("table", { class: "data compact", id: "preanalysis-rmse" },
      el("thead", {}, el("tr", {}, el("th", { text: "" }), ["E", "N", "U", "planimetric", "3D"].map((h) => el("th", { class: "num", text: h })))),
      el("tbody", {}, el("tr", {}, el("th", { text: "predicted check RMSE (m)" }),
        ["e", "n", "u", "planimetric", "3d"].map((c) => el("td", { class: "num", text: fmtNum(pr[c], 3) })))))));
    const rows = [...(cp.points || []).map((p) => ({ ...p, role: "check" })), ...(report.points || [])];
    box.append(el("details", { open: true }, el("summary", { text: `Predicted precision of the ${rows.length} planned points` }),
      el("div", { class: "table-wrap" }, el("table", { class: "data", id: "preanalysis-points" },
        el("thead", {}, el("tr", {}, el("th", { text: "point" }), el("th", { text: "role" }),
          ["σE (m)", "σN (m)", "σU (m)", "ellipse a (m)", "ellipse b (m)", "azimuth (°)"].map((h) => el("th", { class: "num", text: h })), el("th", { text: "images" }))),
        el("tbody", {}, rows.map((p) => el("tr", {}, el("td", {}, el("code", { text: p.id })), el("td", { text: p.role }),
          ["e", "n", "u"].map((c) => el("td", { class: "num", text: fmtNum((p.sigma_m || {})[c], 3) })),
          el("td", { class: "num", text: fmtNum((p.error_ellipse || {}).semi_major_m, 3) }),
          el("td", { class: "num", text: fmtNum((p.error_ellipse || {}).semi_minor_m, 3) }),
          el("td", { class: "num", text: fmtNum((p.error_ellipse || {}).azimuth_deg, 1) }),
          el("td", { class: "muted", text: (p.images || []).length }))))))));
    const warn = (report.quality || {}).warnings || [];
    if (warn.length) box.append(el("div", { class: "warnings" }, el("strong", { text: "Warnings" }), el("ul", {}, warn.map((w) => el("li", { text: w.message })))));
  }

  // Leave-one-out (issue 15): each control point withheld in turn, from the solution.
  function renderLeaveOneOut(box, report) {
    const loo = (report.quality || {}).leave_one_out;
    if (!loo || !(loo.points || []).length) return;
    const comps = ["e", "n", "u"];
    const rm = loo.rmse_m || {}, pr = loo.predicted_rmse_m || {};
    box.append(el("h3", { text: "Leave-one-out of the control points" }));
    box.append(el("p", { class: "muted", text: `Each control point withheld in turn and computed from the orientation adjusted without it (${loo.method}). Cross-validation RMSE E ${fmtNum(rm.e, 3)} m, N ${fmtNum(rm.n, 3)} m, U ${fmtNum(rm.u, 3)} m; predicted E ${fmtNum(pr.e, 3)}, N ${fmtNum(pr.n, 3)}, U ${fmtNum(pr.u, 3)}; ${loo.n_discrepancy_test_failed} of ${loo.n_determined} fail the discrepancy test.` }));
    box.append(el("details", {}, el("summary", { text: `Leave-one-out table (${loo.points.length} control points)` }),
      el("div", { class: "table-wrap" }, el("table", { class: "data", id: "leave-one-out" },
        el("thead", {}, el("tr", {}, el("th", { text: "point" }),
          ["dE (m)", "dN (m)", "dU (m)", "σE (m)", "σN (m)", "σU (m)", "χ² / critical"].map((h) => el("th", { class: "num", text: h })), el("th", { text: "test" }))),
        el("tbody", {}, loo.points.map((p) => el("tr", {}, el("td", {}, el("code", { text: p.id })),
          comps.map((c) => el("td", { class: "num", text: fmtNum((p.discrepancy_m || {})[c], 3) })),
          comps.map((c) => el("td", { class: "num", text: fmtNum((p.sigma_m || {})[c], 3) })),
          el("td", { class: "num", text: p.discrepancy_test ? `${fmtNum(p.discrepancy_test.statistic, 2)} / ${fmtNum(p.discrepancy_test.critical, 2)}` : "–" }),
          el("td", {}, p.discrepancy_test ? verdict(p.discrepancy_test.passed, "passed", "rejected") : el("span", { class: "muted", text: p.determined ? "–" : "not determined" })))))))));
  }

  function renderParsimony(box, report) {
    const par = (report.quality || {}).parsimony;
    if (!par || !(par.steps || []).length) return;
    box.append(el("details", {}, el("summary", { text: `Parsimony: ${(par.dropped || []).length} platform terms dropped` }),
      el("p", { class: "muted", text: par.rule || "" }),
      el("div", { class: "table-wrap" }, el("table", { class: "data compact" },
        el("thead", {}, el("tr", {}, ["step", "term", "|value| / σ", "F / critical", "decision", "σ0", "check 3D (m)"].map((h, i) => el("th", { class: i === 1 || i === 4 ? null : "num", text: h })))),
        el("tbody", {}, par.steps.map((st) => el("tr", {},
          el("td", { class: "num", text: st.step }),
          el("td", {}, el("code", { text: st.term.name })),
          el("td", { class: "num", text: fmtNum(st.term.ratio, 3) }),
          el("td", { class: "num", text: st.test ? `${fmtNum(st.test.statistic, 2)} / ${fmtNum(st.test.critical, 2)}` : "–" }),
          el("td", { text: st.decision }),
          el("td", { class: "num", text: fmtNum(st.sigma0, 4) }),
          el("td", { class: "num", text: fmtNum(st.check_rmse_3d_m, 3) }))))))));
  }

  // Measured attitude weighted in the adjustment: per attitude block, the residual RMS and
  // largest residual of roll, pitch and yaw next to the sigma they were given.
  function renderAttitude(box, report) {
    const blocks = report.attitude || [];
    if (!blocks.length) return;
    const angles = ["roll", "pitch", "yaw"];
    box.append(el("h3", { text: "Measured attitude" }));
    box.append(el("p", { class: "legend-line", text: "Residuals (measured − adjusted) of the weighted attitude samples, degrees; RMS well above σ means the attitude data and the images disagree (misalignment, wrong time scale or frame)." }));
    box.append(el("div", { class: "table-wrap" }, el("table", { class: "data", dataset: { attitude: "1" } },
      el("thead", {}, el("tr", {}, el("th", { text: "images" }), el("th", { class: "num", text: "samples" }),
        angles.map((a) => el("th", { class: "num", text: `${a} RMS / max / σ` })))),
      el("tbody", {}, blocks.map((b) => el("tr", {},
        el("td", {}, el("code", { text: (b.images || []).join(", ") })),
        el("td", { class: "num", text: b.n_samples }),
        angles.map((_, k) => el("td", { class: "num",
          text: `${fmtNum(b.rms_residual_deg[k], 4)} / ${fmtNum(b.max_abs_residual_deg[k], 4)} / ${fmtNum(b.sigma_deg[k], 4)}` }))))))));
  }

  function renderParameters(box, report) {
    const corr = report.correlations || {};
    const threshold = corr.threshold ?? 0.75;
    const partners = new Map(); // "image/param" -> [[other, rho]]
    for (const p of corr.pairs || []) {
      for (const [a, b] of [[p.a, p.b], [p.b, p.a]]) {
        if (!partners.has(a)) partners.set(a, []);
        partners.get(a).push([b, p.rho]);
      }
    }
    box.append(el("h3", { text: "Parameters" }));
    box.append(el("p", { class: "legend-line" },
      "Flags: ", el("span", { class: "flag corr", text: "ρ" }), ` correlated with another parameter at |ρ| ≥ ${threshold} (hover for the partners), `,
      el("span", { class: "flag ns", text: "n.s." }), " not significant (|value| < σ), ",
      el("span", { class: "flag fixed", text: "fixed" }), " not estimated."));
    const paramRow = (key, p) => {
      const flags = [];
      const with_ = partners.get(key);
      if (with_) {
        const maxRho = Math.max(...with_.map(([, r]) => Math.abs(r)));
        flags.push(el("span", { class: "flag corr", title: with_.map(([o, r]) => `${o}: ${r.toFixed(3)}`).join("\n"), text: `ρ ${maxRho.toFixed(2)}` }));
      }
      const notSignificant = p.significant === false ||
        (p.significant === undefined && p.estimated && p.sigma !== null && p.sigma !== undefined && Math.abs(p.value) < p.sigma);
      if (p.estimated && notSignificant) {
        flags.push(el("span", { class: "flag ns", title: "|value| < sigma: not significantly different from zero", text: "n.s." }));
      }
      if (!p.estimated) flags.push(el("span", { class: "flag fixed", text: "fixed" }));
      return el("tr", { class: flags.length && p.estimated ? "flagged" : null },
        el("td", {}, el("code", { text: p.name })),
        el("td", { class: "num", text: fmtValue(p.value, p.sigma) }),
        el("td", { class: "num", text: p.estimated ? fmtSig(p.sigma, 2) : "–" }),
        el("td", { text: (p.unit || "").replace("^2", "²").replace("^3", "³") }),
        el("td", {}, flags));
    };
    const paramTable = (title, meta, data, rows) => el("div", { class: "param-card" },
      el("h4", {}, el("span", {}, el("code", { text: title })), el("span", { class: "meta", text: meta })),
      el("div", { class: "table-wrap" }, el("table", { class: "data params", dataset: data },
        el("thead", {}, el("tr", {}, el("th", { text: "parameter" }), el("th", { class: "num", text: "value" }),
          el("th", { class: "num", text: "σ" }), el("th", { text: "unit" }), el("th", { text: "flags" }))),
        el("tbody", {}, rows))));
    const grid = el("div", { class: "param-grid" });
    for (const im of report.images || []) {
      const rm = im.residual_rmse || {};
      grid.append(paramTable(im.id,
        `${im.model || ""} · ${im.frame || ""} · ${im.n_observations ?? "?"} obs · RMSE ${fmtNum(rm.line_px, 2)} / ${fmtNum(rm.column_px, 2)} px`,
        { image: im.id }, (im.parameters || []).map((p) => paramRow(`${im.id}/${p.name}`, p))));
    }
    for (const ps of report.passes || []) {
      grid.append(paramTable(`pass ${ps.id}`,
        `${ps.model || ""} · ECEF state at t = ${fmtNum(ps.reference_epoch_s, 3)} s · images ${(ps.images || []).join(", ")}`,
        { pass: ps.id }, (ps.parameters || []).map((p) => paramRow(`pass:${ps.id}/${p.name}`, p))));
    }
    for (const cam of report.cameras || []) {
      if (!(cam.parameters || []).length) continue;
      grid.append(paramTable(`camera ${cam.id}`, `interior orientation${cam.master_chip ? ` · master chip ${cam.master_chip}` : ""}`,
        { camera: cam.id }, cam.parameters.map((p) => paramRow(`camera:${cam.id}/${p.name}`, p))));
    }
    box.append(grid);
    const pairs = corr.pairs || [];
    if (pairs.length) {
      box.append(el("details", {}, el("summary", { text: `${pairs.length} correlation pairs with |ρ| ≥ ${threshold}${corr.truncated ? " (truncated)" : ""}` }),
        el("div", { class: "table-wrap" }, el("table", { class: "data" },
          el("thead", {}, el("tr", {}, el("th", { text: "parameter" }), el("th", { text: "parameter" }), el("th", { class: "num", text: "ρ" }))),
          el("tbody", {}, pairs.map((p) => el("tr", {}, el("td", {}, el("code", { text: p.a })), el("td", {}, el("code", { text: p.b })),
            el("td", { class: "num", text: p.rho.toFixed(3) }))))))));
    }
  }

  function renderParameterAnalysis(box, report) {
    const pa = report.parameter_analysis;
    if (!pa || !(pa.steps || []).length) return;
    box.append(el("details", {}, el("summary", { text: `Significance analysis: ${(pa.dropped || []).length} parameters dropped` }),
      el("p", { class: "muted", text: pa.rule || "" }),
      el("div", { class: "table-wrap" }, el("table", { class: "data compact" },
        el("thead", {}, el("tr", {}, ["step", "σ0", "IOP", "check planimetric (m)", "dropped", "|value| / σ"].map((h, i) => el("th", { class: i === 4 ? null : "num", text: h })))),
        el("tbody", {}, pa.steps.map((st) => el("tr", {},
          el("td", { class: "num", text: st.step }),
          el("td", { class: "num", text: fmtNum(st.sigma0, 4) }),
          el("td", { class: "num", text: st.n_iop ?? "–" }),
          el("td", { class: "num", text: fmtNum((st.check_rmse_m || {}).planimetric, 3) }),
          el("td", {}, st.dropped ? el("code", { text: st.dropped.name }) : "–"),
          el("td", { class: "num", text: st.dropped ? fmtNum(st.dropped.ratio, 3) : "–" }))))))));
  }

  function renderCheckpoints(box, report) {
    const cp = report.checkpoints;
    box.append(el("h3", { text: "Check points" }));
    if (!cp || !cp.n) { box.append(el("p", { class: "muted", text: "This job has no check points." })); return; }
    const comps = ["e", "n", "u", "planimetric"];
    const head = el("tr", {}, el("th", { text: "" }), comps.map((c) => el("th", { class: "num", text: c === "planimetric" ? "planimetric" : c.toUpperCase() })));
    const numRow = (label, obj, digits = 3) => el("tr", {}, el("th", { text: label }),
      comps.map((c) => el("td", { class: "num", text: fmtNum(obj ? obj[c] : null, digits) })));
    const testRow = (label, tests, cell) => el("tr", {}, el("th", { text: label }),
      comps.map((c) => el("td", { class: "num" }, tests && tests[c] ? cell(tests[c]) : el("span", { class: "muted", text: "–" }))));
    box.append(el("p", { class: "muted", text: `${cp.n} check points, ${cp.method || "?"}; GSD ${fmtNum(cp.gsd_m, 2)} m; discrepancy = estimated − known, in the local geodetic system` }));
    box.append(el("div", { class: "table-wrap" }, el("table", { class: "data compact", id: "checkpoint-stats" },
      el("thead", {}, head),
      el("tbody", {},
        numRow("mean (m)", cp.mean_m), numRow("std (m)", cp.std_m), numRow("RMSE (m)", cp.rmse_m),
        numRow("RMSE (GSD)", cp.rmse_gsd, 2),
        numRow("predicted RMSE (m)", cp.predicted_rmse_m),
        numRow("RMSE / predicted", cp.rmse_ratio, 2),
        testRow("t-test (bias)", cp.t_test, (t) => el("span", {}, `t ${fmtNum(t.statistic, 2)} / ${fmtNum(t.critical, 2)} `, verdict(t.passed, "no bias", "biased"))),
        testRow("Shapiro-Wilk", cp.shapiro_wilk, (t) => el("span", {}, `W ${fmtNum(t.statistic, 3)}, p ${fmtNum(t.p_value, 3)} `, verdict(t.passed, "normal", "not normal")))))));
    const pts = cp.points || [];
    if (pts.length) {
      box.append(el("details", {}, el("summary", { text: `Discrepancies of the ${pts.length} check points` }),
        el("div", { class: "table-wrap" }, el("table", { class: "data" },
          el("thead", {}, el("tr", {}, el("th", { text: "point" }), ["E (m)", "N (m)", "U (m)", "planimetric (m)", "σE (m)", "σN (m)", "σU (m)"].map((h) => el("th", { class: "num", text: h })), el("th", { text: "test" }), el("th", { text: "images" }))),
          el("tbody", {}, pts.map((p) => el("tr", {}, el("td", {}, el("code", { text: p.id })),
            comps.map((c) => el("td", { class: "num", text: fmtNum((p.discrepancy_m || {})[c], 3) })),
            ["e", "n", "u"].map((c) => el("td", { class: "num", text: fmtNum((p.sigma_m || {})[c], 3) })),
            el("td", {}, p.discrepancy_test ? verdict(p.discrepancy_test.passed, "passed", "rejected") : el("span", { class: "muted", text: "–" })),
            el("td", { class: "muted", text: (p.images || []).join(", ") }))))))));
    }
  }

  // -- plots ---------------------------------------------------------------------------------------
  async function renderPlots(box, jobId, model) {
    clear(box).append(el("h3", { text: "Plots" }));
    const id = encodeURIComponent(jobId);
    let index;
    try {
      index = await api(`jobs/${id}/plots${model ? `?model=${encodeURIComponent(model)}` : ""}`);
    } catch (err) {
      box.append(el("p", { class: "error-box", text: `No plots: ${err.message}` }));
      return;
    }
    const imageSelect = el("select", { id: "plot-image" }, el("option", { value: "", text: "all images" }),
      (index.images || []).map((im) => el("option", { value: im, text: im })));
    const grid = el("div", { class: "plots", id: "plots" });
    box.append(el("div", { class: "plots-bar" }, el("label", {}, "Per-image plots:", imageSelect),
      el("span", { class: "muted", text: "Click a PNG or SVG link to download the image." })), grid);
    const order = ["model-rmse", "planimetric-discrepancies", "error-ellipses", "height-discrepancies", "image-residuals",
      "residual-histograms", "cost", "correlations"];
    const rank = (k) => (order.includes(k) ? order.indexOf(k) : order.length);
    const plots = [...index.plots].sort((a, b) => rank(a.kind) - rank(b.kind));
    const draw = () => {
      clear(grid);
      for (const p of plots) {
        const params = new URLSearchParams();
        if (model) params.set("model", model);
        if (p.per_image && imageSelect.value) params.set("image", imageSelect.value);
        const q = params.toString() ? `?${params}` : "";
        const base = `jobs/${id}/plots/${p.kind}`;
        const img = el("img", { alt: p.title, dataset: { kind: p.kind }, loading: "eager" });
        // figures of several panels take the whole row
        const panels = p.per_image && !imageSelect.value ? (index.images || []).length : 1;
        const wide = ["planimetric-discrepancies", "height-discrepancies"].includes(p.kind) ||
          (["image-residuals", "correlations"].includes(p.kind) && panels > 1);
        const fig = el("figure", { class: wide ? "wide" : null, dataset: { kind: p.kind } }, img,
          el("figcaption", {}, el("span", { title: p.description }, el("strong", { text: p.title }), " – ", p.description),
            el("span", { class: "fmt" }, download(`${base}.png${q}`, `${p.kind}.png`, "PNG"), download(`${base}.svg${q}`, `${p.kind}.svg`, "SVG"))));
        grid.append(fig);
        api(`${base}.png${q}`, { as: "blob" }).then((blob) => {
          const url = URL.createObjectURL(blob);
          state.blobUrls.push(url);
          img.src = url;
        }).catch((err) => {
          img.replaceWith(el("div", { class: "plot-error", text: `${p.title}: ${err.message}` }));
        });
      }
    };
    imageSelect.addEventListener("change", draw);
    draw();
  }

  // -- readiness: /readyz says whether the workers can take jobs (they load the solver and
  // compile its kernels at start, minutes on a fresh installation) ------------------------------
  const READY_POLL_MS = 5000;
  async function checkReadiness() {
    const box = $("readiness");
    let body = null;
    let ok = false;
    try {
      const r = await fetch("readyz", { headers: { Accept: "application/json" } });
      ok = r.ok;
      try { body = await r.json(); } catch (e) { body = null; }
    } catch (e) {
      body = null;
    }
    if (ok) {
      box.hidden = true;
      box.textContent = "";
      return;
    }
    const checks = (body && body.checks) || {};
    const why = Object.entries(checks).filter(([k]) => k !== "evaluation").map(([k, v]) => `${k}: ${v}`).join("; ");
    box.textContent = "The server is not ready yet: jobs you submit wait until its workers are" + (why ? ` (${why}).` : ".");
    box.hidden = false;
    setTimeout(checkReadiness, READY_POLL_MS);
  }

  // -- start ---------------------------------------------------------------------------------------
  function init() {
    initKey();
    checkReadiness();
    initInput();
    $("cancel").addEventListener("click", cancelCurrent);
    $("jobs-refresh").addEventListener("click", refreshJobs);
    initExamples();
    initModels();
    refreshJobs();
    const m = /job=([^&]+)/.exec(location.hash);
    if (m) openJob(decodeURIComponent(m[1]));
  }
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init);
  else init();
})();
