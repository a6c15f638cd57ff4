// Pushbroom orientation server: the job builder of the web page. Plain JavaScript, no build step.
// Files dropped (or chosen) here are recognised by name and header, listed with their role and
// image; sensors come from the camera library (GET /cameras: your cameras and the shared ones,
// with the sensor presets) or from uploaded camera JSON files. Every change recomposes the job
// on the server (POST /jobs/compose, multipart: the files and a JSON spec); its problems are
// shown beside the file they name (file, line, column), a header that is not recognised gets a
// column map, and the generated JSON is shown. "Use and submit" hands the document to the main
// editor and submits it there (same validation, progress and result views). "Find tie points"
// runs the match process (POST processes/match/execution) on the dropped rasters (uploaded,
// base64) or rasters named in the user's folder on the server, guided by the composed job, and
// adds the tie points it finds as one measurement file per image.
"use strict";

(() => {
  const KEY_STORAGE = "pba.apiKey";
  const $ = (id) => document.getElementById(id);
  const KINDS = {
    points: "survey (role column)",
    gcps: "control points",
    checks: "check points",
    measurements: "image measurements",
    state: "header state",
    ephemeris: "ephemeris",
    attitude: "attitude",
    attitude_base: "attitude base (the delivered attitude)",
    rpc: "RPC of an image (RPC00B)",
    sensor: "vendor sensor metadata (the formats the server reads)",
    cameras: "camera file (JSON)",
    raster: "raster of an image (for tie points)",
    dem: "DEM (heights of the tie points)",
    asp_gcp: "ASP GCP (several images)",
    ignore: "ignore",
  };
  const PER_IMAGE = new Set(["measurements", "state", "ephemeris", "attitude", "attitude_base", "rpc", "sensor", "raster"]);
  const NOT_COMPOSED = new Set(["ignore", "raster"]);  // rasters go to the match process, not to compose
  const RASTER = /\.(tiff?|jp2|ntf|img)$/i;
  const RPC_MODELS = ["RPC-SHIFT", "RPC-DRIFT", "RPC-AFFINE"];
  const CANONICAL = {
    points: ["id", "x", "y", "z", "sx", "sy", "sz", "role"],
    gcps: ["id", "x", "y", "z", "sx", "sy", "sz"],
    checks: ["id", "x", "y", "z", "sx", "sy", "sz"],
    measurements: ["image", "point", "line", "column", "sigma_px", "chip"],
    state: ["time_s", "x", "y", "z", "vx", "vy", "vz"],
    ephemeris: ["time_s", "x", "y", "z", "vx", "vy", "vz"],
    attitude: ["time_s", "roll_deg", "pitch_deg", "yaw_deg"],
    attitude_base: ["time_s", "roll_deg", "pitch_deg", "yaw_deg"],
  };
  const st = { files: [], library: [], cameras: {}, timer: null, seq: 0, job: null, valid: false, columns: {}, sensorFormats: [], formatsLoaded: Promise.resolve() };

  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === undefined || v === null || v === false) continue;
      if (k === "text") e.textContent = String(v);
      else if (k === "class") e.className = v;
      else e.setAttribute(k, v === true ? "" : String(v));
    }
    for (const c of children) if (c !== null && c !== undefined) e.append(c);
    return e;
  }

  function headers() {
    const key = sessionStorage.getItem(KEY_STORAGE) || "";
    return key ? { "X-API-Key": key, Accept: "application/json" } : { Accept: "application/json" };
  }

  // the header line of a table (first line that is neither blank nor a # comment)
  function headerOf(text) {
    for (const line of text.split(/\r?\n/)) {
      const s = line.trim();
      if (!s || s.startsWith("#")) continue;
      const counts = [",", ";", "\t"].map((d) => [d, s.split(d).length - 1]);
      counts.sort((a, b) => b[1] - a[1]);
      const d = counts[0][1] ? counts[0][0] : ",";
      return s.split(d).map((h) => h.trim().replace(/^"|"$/g, ""));
    }
    return [];
  }

  // the sensor format a file name names alone (a format's file_names, globs in any case): the
  // image is the name without the glob's literal prefix and its extension (DIM_N.XML -> N)
  function sensorFileName(name, stem) {
    for (const f of st.sensorFormats) {
      for (const glob of f.file_names) {
        const g = glob.toLowerCase();
        const re = new RegExp("^" + g.split("*").map((s) => s.replace(/[.+?^${}()|[\]\\]/g, "\\$&")).join(".*") + "$");
        if (re.test(name.toLowerCase())) return { kind: "sensor", image: stem.slice(g.split("*")[0].length) };
      }
    }
    return null;
  }

  function guess(name, text) {
    const lower = name.toLowerCase();
    const stem = name.replace(/\.[^.]+$/, "");
    // a DEM: SRTM's .hgt tiles, or a raster whose name says so (any raster can be set to DEM)
    if (lower.endsWith(".hgt") || (RASTER.test(name) && /(^|[-_.])(dem|dsm|dtm|srtm|copdem|cop30|glo30)([-_.]|$)/.test(lower))) return { kind: "dem" };
    if (RASTER.test(name)) return { kind: "raster", image: stem };
    if (lower.endsWith(".json")) return { kind: "cameras" };
    // an image's RPC: GDAL's NAME_RPC.TXT, NAME.RPB, a DIMAP RPC_NAME.XML (a raster's RPC: its sidecar, or pba import-rpc)
    if (lower.endsWith("_rpc.txt")) return { kind: "rpc", image: name.slice(0, -8) };
    if (lower.endsWith(".rpb")) return { kind: "rpc", image: stem };
    if (lower.startsWith("rpc_") && lower.endsWith(".xml")) return { kind: "rpc", image: stem.slice(4) };
    // vendor sensor metadata (camera, ephemeris, attitude, line times): the formats the server
    // reads (GET jobs/compose/formats): a file name that names one (DIM_NAME.XML: image NAME), or
    // an XML file whose root is one of theirs
    const sensor = sensorFileName(name, stem);
    if (sensor) return sensor;
    const roots = st.sensorFormats.flatMap((f) => f.roots);
    if (lower.endsWith(".xml") && roots.length && new RegExp(`<(${roots.join("|")})[\\s>]`).test(text.slice(0, 4096))) {
      return { kind: "sensor", image: stem };
    }
    if (lower.endsWith(".points") || lower.endsWith(".gcp")) return { kind: "measurements", image: stem };
    if (lower.endsWith(".attitude-base.csv")) return { kind: "attitude_base", image: name.slice(0, -18) };  // pba job-sources' name
    for (const k of ["state", "ephemeris", "attitude"]) {
      if (lower.endsWith(`.${k}.csv`)) return { kind: k, image: name.slice(0, -(k.length + 5)) };
    }
    const h = headerOf(text).map((x) => x.toLowerCase());
    const has = (...names) => names.some((n) => h.includes(n));
    if (has("line", "row") && has("column", "col", "sample")) {
      return { kind: "measurements", image: stem.replace(/[-_]ties$/, "") };
    }
    if (has("role", "type")) return { kind: "points" };
    if (has("x", "e", "easting", "lon", "longitude") && has("y", "n", "northing", "lat", "latitude")) return { kind: "gcps" };
    return { kind: "measurements", image: stem };
  }

  async function addFiles(list) {
    const files = Array.from(list);  // before waiting: the input's FileList is emptied after the call
    await st.formatsLoaded;  // a vendor file is recognised by the formats the server reads: wait for them
    for (const f of files) {
      const text = RASTER.test(f.name) ? "" : await f.text();
      const old = st.files.findIndex((x) => x.name === f.name);
      const entry = { name: f.name, file: f, text, ...guess(f.name, text), problems: [] };
      if (entry.kind === "cameras") {
        try {
          const doc = JSON.parse(text);
          const items = Array.isArray(doc) ? doc : doc.cameras || [doc];
          for (const c of items) if (c && typeof c.id === "string") st.cameras[c.id] = f.name;
        } catch (e) { entry.problems = [`not JSON: ${e.message}`]; }
      }
      if (old >= 0) st.files[old] = entry; else st.files.push(entry);
    }
    render();
    schedule(0);
  }

  function imageIds() {
    const ids = [];
    for (const f of st.files) if (PER_IMAGE.has(f.kind) && f.kind !== "raster" && f.image && !ids.includes(f.image)) ids.push(f.image);
    return ids;
  }

  function renderFiles() {
    const body = $("builder-files").querySelector("tbody");
    body.replaceChildren();
    st.files.forEach((f, i) => {
      const kind = el("select", { "data-file": f.name, class: "b-kind" });
      for (const [k, label] of Object.entries(KINDS)) kind.append(el("option", { value: k, text: label, selected: k === f.kind }));
      kind.addEventListener("change", () => { f.kind = kind.value; render(); schedule(); });
      const image = el("input", { value: f.image || "", class: "b-image", "data-file": f.name, list: "builder-image-ids", hidden: !PER_IMAGE.has(f.kind) });
      image.addEventListener("change", () => { f.image = image.value.trim(); render(); schedule(); });
      const status = el("td", { class: "b-status" });
      for (const p of f.problems) status.append(el("div", { class: "problem", text: p }));
      if (!f.problems.length && st.job) status.append(el("span", { class: "ok", text: "✓" }));
      const remove = el("button", { type: "button", class: "secondary small", text: "remove" });
      remove.addEventListener("click", () => { st.files.splice(i, 1); render(); schedule(); });
      body.append(el("tr", { "data-file": f.name }, el("td", { text: f.name }), el("td", {}, kind), el("td", {}, image), status, el("td", {}, remove)));
      if (f.mapping && CANONICAL[f.kind]) body.append(mappingRow(f));
    });
    const dl = $("builder-image-ids");
    dl.replaceChildren(...imageIds().map((id) => el("option", { value: id })));
  }

  // a column map for a file whose header the server did not recognise
  function mappingRow(f) {
    const cell = el("td", { colspan: 5, class: "b-mapping" }, el("span", { class: "muted", text: "Map the columns: " }));
    const map = st.columns[f.name] || (st.columns[f.name] = {});
    for (const col of headerOf(f.text)) {
      const sel = el("select", { "data-file": f.name, "data-column": col, class: "b-map" });
      sel.append(el("option", { value: "", text: "(as is)" }));
      for (const c of CANONICAL[f.kind]) sel.append(el("option", { value: c, text: c, selected: map[col] === c }));
      sel.addEventListener("change", () => {
        if (sel.value) map[col] = sel.value; else delete map[col];
        schedule();
      });
      cell.append(el("label", {}, `${col} → `, sel));
    }
    return el("tr", { class: "mapping" }, cell);
  }

  function renderImages() {
    const box = $("builder-images");
    box.replaceChildren();
    for (const id of imageIds()) {
      if (st.files.some((f) => f.kind === "sensor" && f.image === id)) {
        // its metadata brings its camera, ephemeris, attitude and model
        box.append(el("label", {}, `${id}: from its sensor metadata`));
        continue;
      }
      if (st.files.some((f) => f.kind === "rpc" && f.image === id)) {
        // an RPC image: no sensor, a bias model instead
        const chosen = (st.rpcModel || {})[id] || "RPC-DRIFT";
        const sel = el("select", { "data-image": id, class: "b-rpc-model" });
        for (const m of RPC_MODELS) sel.append(el("option", { value: m, text: m, selected: m === chosen }));
        sel.addEventListener("change", () => { (st.rpcModel = st.rpcModel || {})[id] = sel.value; schedule(); });
        box.append(el("label", {}, `${id} (RPC): `, sel));
        continue;
      }
      const sel = el("select", { "data-image": id, class: "b-camera" });
      const names = [...Object.keys(st.cameras), ...st.library.filter((n) => !(n in st.cameras))];
      const chosen = st.choice && st.choice[id] ? st.choice[id] : (names.includes(id) ? id : "");
      sel.append(el("option", { value: "", text: "choose a sensor" }));
      for (const n of names) sel.append(el("option", { value: n, text: n in st.cameras ? `${n} (${st.cameras[n]})` : n, selected: n === chosen }));
      sel.addEventListener("change", () => { (st.choice = st.choice || {})[id] = sel.value; schedule(); });
      box.append(el("label", {}, `${id}: `, sel));
    }
    if (!box.childElementCount) box.append(el("span", { class: "muted", text: "Images appear with their measurement files." }));
  }

  function render() { renderFiles(); renderImages(); }

  function spec() {
    const images = imageIds().map((id) => {
      const im = { id, measurements: [] };
      for (const f of st.files) {
        if (f.image !== id) continue;
        if (f.kind === "measurements") im.measurements.push(f.name);
        else if (PER_IMAGE.has(f.kind) && !NOT_COMPOSED.has(f.kind)) im[f.kind] = f.name;
      }
      const cam = document.querySelector(`select.b-camera[data-image="${CSS.escape(id)}"]`);
      if (cam && cam.value) im.camera = cam.value;
      const rpcModel = document.querySelector(`select.b-rpc-model[data-image="${CSS.escape(id)}"]`);
      if (im.rpc && rpcModel) im.rpc_model = rpcModel.value;
      return im;
    });
    const of = (kind) => st.files.filter((f) => f.kind === kind).map((f) => f.name);
    const models = $("b-models").value.split(/[\s,]+/).filter(Boolean);
    const out = {
      name: $("b-name").value || "job",
      crs: $("b-crs").value.trim() || null,
      models: models.length ? models : ["K2"],
      images,
      points: of("points"), gcps: of("gcps"), checks: of("checks"), asp_gcp: of("asp_gcp"),
      camera_files: of("cameras"),
      sigma_px: Number($("b-sigma").value) || 0.5,
      time_scale: $("b-time-scale").value.trim() || null,
      bias_prior_px: Number($("b-bias-prior").value) || null,
      columns: Object.fromEntries(Object.entries(st.columns).filter(([, m]) => Object.keys(m).length)),
    };
    const dem = of("dem");
    if (dem.length) {
      out.dem = dem[0];
      out.dem_sigma_m = Number($("b-dem-sigma").value) || 5;
      out.dem_vertical = $("b-dem-vertical").value || null;
    }
    const opt = $("b-options").value.trim();
    out.options = opt ? JSON.parse(opt) : {};
    return out;
  }

  function schedule(delay = 400) {
    clearTimeout(st.timer);
    st.timer = setTimeout(compose, delay);
  }

  function setStatus(text, bad) {
    const s = $("builder-status");
    s.textContent = text;
    s.className = bad ? "bad" : "ok";
  }

  async function compose() {
    const seq = ++st.seq;
    for (const f of st.files) { f.problems = []; }
    st.job = null; st.valid = false;
    $("builder-submit").disabled = true;
    updateMatch();
    if (!imageIds().length) { render(); setStatus("Add measurement files (CSV, QGIS .points, ASP .gcp) or the images' RPCs.", true); return; }
    let body;
    try { body = spec(); } catch (e) { setStatus(`Options: not JSON (${e.message})`, true); return; }
    const form = new FormData();
    form.append("spec", JSON.stringify(body));
    for (const f of st.files) if (!NOT_COMPOSED.has(f.kind)) form.append("files", f.file, f.name);
    setStatus("composing…", false);
    let r, doc;
    try {
      r = await fetch("jobs/compose", { method: "POST", headers: headers(), body: form });
      doc = await r.json();
    } catch (e) { if (seq === st.seq) setStatus(`Not composed: ${e.message}`, true); return; }
    if (seq !== st.seq) return;
    const general = [];
    if (!r.ok) {
      for (const e of doc.errors || []) {
        const f = e.file && st.files.find((x) => x.name === e.file);
        if (f) {
          f.problems.push(e.message);
          if (e.code === "unrecognised_header") f.mapping = true;
        } else general.push(`${e.pointer || ""} ${e.message}`.trim());
      }
      render();
      showJob(null, general.length ? general : [doc.detail || "the files have problems"]);
      setStatus(`${(doc.errors || []).length} problem(s): see beside the files`, true);
      return;
    }
    st.job = doc.job;
    st.valid = !!doc.validation.valid;
    render();
    const lines = summaryLines(doc.summary);
    for (const n of doc.notes || []) lines.push(`note: ${n}`);
    for (const p of doc.validation.problems || []) general.push(`${p.pointer || ""} ${p.message}`.trim());
    showJob(doc.job, general, lines);
    if (st.valid) setStatus(`valid: ${doc.validation.n_observations} observations, ${doc.validation.dof} degrees of freedom`, false);
    else setStatus("composed, but the checks refuse it: see the problems", true);
    $("builder-submit").disabled = !st.valid;
    updateMatch();
  }

  // ---- find tie points: the match process on the rasters, guided by the composed job ----
  function serverRasters() {
    const out = [];
    for (const part of $("b-raster-paths").value.split(",")) {
      const s = part.trim();
      const eq = s.indexOf("=");
      if (eq > 0) out.push({ id: s.slice(0, eq).trim(), path: s.slice(eq + 1).trim() });
    }
    return out;
  }

  function matchRasters() {
    const named = serverRasters();
    const uploads = st.files.filter((f) => f.kind === "raster" && f.image && !named.some((r) => r.id === f.image));
    return { named, uploads };
  }

  function updateMatch() {
    const { named, uploads } = matchRasters();
    $("builder-match").disabled = !st.job || named.length + uploads.length < 2 || st.matching;
  }

  function setMatchStatus(text, bad) {
    const s = $("builder-match-status");
    s.textContent = text;
    s.className = bad ? "bad" : "ok";
  }

  function base64Of(file) {
    return new Promise((resolve, reject) => {
      const reader = new FileReader();
      reader.onload = () => resolve(String(reader.result).split(",", 2)[1] || "");
      reader.onerror = () => reject(reader.error);
      reader.readAsDataURL(file);
    });
  }

  function problemText(doc) {
    const first = (doc.errors || doc.problems || [])[0];
    return [doc.detail || doc.message || "", first ? `${first.pointer || ""} ${first.message || ""}`.trim() : ""].filter(Boolean).join(": ");
  }

  async function findTiePoints() {
    if (!st.job) return;
    const { named, uploads } = matchRasters();
    const images = [...named];
    for (const f of uploads) images.push({ id: f.image, value: await base64Of(f.file), mediaType: f.file.type || "image/tiff" });
    const inputs = { job: st.job, images };
    const h = $("b-heights").value.split(",").map((x) => Number(x.trim()));
    if (h.length === 2 && h.every((x) => Number.isFinite(x)) && $("b-heights").value.trim()) inputs.heights_m = h;
    st.matching = true;
    updateMatch();
    setMatchStatus("submitting…", false);
    try {
      const r = await fetch("processes/match/execution", {
        method: "POST", headers: { ...headers(), "Content-Type": "application/json", Prefer: "respond-async" },
        body: JSON.stringify({ inputs }),
      });
      const doc = await r.json();
      if (!r.ok) { setMatchStatus(`refused: ${problemText(doc)}`, true); return; }
      let status = doc;
      while (!["successful", "failed", "dismissed"].includes(status.status)) {
        setMatchStatus(`matching: ${status.status} ${status.progress || 0}% ${status.message || ""}`, false);
        await new Promise((res) => setTimeout(res, 500));
        status = await (await fetch(`jobs/${doc.jobID}`, { headers: headers() })).json();
      }
      if (status.status !== "successful") {
        const res = await fetch(`jobs/${doc.jobID}/results`, { headers: headers() });
        setMatchStatus(`no tie points: ${problemText(await res.json())}`, true);
        return;
      }
      const result = (await (await fetch(`jobs/${doc.jobID}/results`, { headers: headers() })).json()).report;
      addTies(result);
    } catch (e) {
      setMatchStatus(`matching failed: ${e.message}`, true);
    } finally {
      st.matching = false;
      updateMatch();
    }
  }

  // the matched tie points as one measurement file per image (the composer reads them as tie points)
  function addTies(result) {
    const byImage = {};
    for (const o of result.observations) (byImage[o.image] = byImage[o.image] || []).push(o);
    const files = [];
    for (const [id, rows] of Object.entries(byImage)) {
      const text = ["point,line,column,sigma_px", ...rows.map((o) => `${o.point},${o.line},${o.column},${o.sigma_px}`)].join("\n") + "\n";
      files.push(new File([text], `${id}-matched-ties.csv`, { type: "text/csv" }));
    }
    const s = result.summary;
    setMatchStatus(`${s.tie_points} tie points, ${s.measurements} measurements added`, false);
    $("builder-match-pairs").replaceChildren(...s.pairs.map((p) => el("div", {
      class: "b-match-pair",
      text: `${p.images[0]}-${p.images[1]}: ${p.matched || 0} matches, ${p.removed_epipolar} removed by the epipolar check, ${p.tie_points} tie points, sigma ${p.sigma_px} px`,
    })));
    addFiles(files).then(() => {
      for (const f of files) {
        const entry = st.files.find((x) => x.name === f.name);
        if (entry) { entry.kind = "measurements"; entry.image = f.name.slice(0, -"-matched-ties.csv".length); }
      }
      render();
      schedule(0);
    });
  }

  function summaryLines(s) {
    const out = [`points: ${s.points.gcp} gcp, ${s.points.check} check, ${s.points.tie} tie`];
    for (const [id, c] of Object.entries(s.images)) out.push(`${id}: ${c.gcp || 0} gcp, ${c.check || 0} check, ${c.tie || 0} tie measured`);
    if (s.single_image.length) out.push(`seen by one image only: ${s.single_image.slice(0, 20).join(", ")}`);
    for (const o of s.outside.slice(0, 20)) out.push(`outside ${o.image}: ${o.point}`);
    if (s.unmeasured.length) out.push(`surveyed but not measured: ${s.unmeasured.slice(0, 20).join(", ")}`);
    return out;
  }

  function showJob(job, problems, lines = []) {
    const box = $("builder-messages");
    box.replaceChildren(
      ...lines.map((t) => el("div", { text: t })),
      ...problems.map((t) => el("div", { class: "problem", text: t })),
    );
    $("builder-json").value = job ? JSON.stringify(job, null, 1) : "";
  }

  function useAndSubmit() {
    if (!st.job) return;
    const models = st.job.options && st.job.options.models;
    $("process").value = models && models.length > 1 ? "model-comparison" : "bundle-adjustment";
    $("process").dispatchEvent(new Event("change", { bubbles: true }));
    if (models && models.length > 1) $("models").value = models.join(",");
    const ta = $("job-text");
    ta.value = JSON.stringify(st.job, null, 2);
    ta.dispatchEvent(new Event("input", { bubbles: true }));
    $("submit").click();
  }

  async function loadLibrary() {
    try {
      const r = await fetch("cameras?limit=1000", { headers: headers() });
      if (!r.ok) return;
      const doc = await r.json();
      st.library = doc.cameras.map((c) => c.name).filter((n, i, a) => a.indexOf(n) === i);
      render();
    } catch (e) { /* the library stays empty; camera files still work */ }
  }

  async function loadFormats() {
    try {
      const r = await fetch("jobs/compose/formats", { headers: headers() });
      if (r.ok) st.sensorFormats = (await r.json()).sensor;
    } catch (e) { /* no sensor formats known: vendor files are then chosen by hand */ }
  }

  function init() {
    const drop = $("builder-drop");
    drop.addEventListener("dragover", (ev) => { ev.preventDefault(); drop.classList.add("dragover"); });
    drop.addEventListener("dragleave", () => drop.classList.remove("dragover"));
    drop.addEventListener("drop", (ev) => {
      ev.preventDefault();
      drop.classList.remove("dragover");
      if (ev.dataTransfer && ev.dataTransfer.files.length) addFiles(ev.dataTransfer.files);
    });
    $("builder-input").addEventListener("change", () => { addFiles($("builder-input").files); $("builder-input").value = ""; });
    for (const id of ["b-name", "b-crs", "b-models", "b-sigma", "b-time-scale", "b-options", "b-bias-prior", "b-dem-sigma", "b-dem-vertical"]) $(id).addEventListener("input", () => schedule());
    $("builder-submit").addEventListener("click", useAndSubmit);
    $("builder-match").addEventListener("click", findTiePoints);
    $("b-raster-paths").addEventListener("input", updateMatch);
    $("key-form").addEventListener("submit", () => setTimeout(loadLibrary, 100));
    render();
    st.formatsLoaded = loadFormats();  // never rejects: without formats, vendor files are chosen by hand
    loadLibrary();
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init);
  else init();
})();
