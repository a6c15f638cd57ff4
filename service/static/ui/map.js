// Map view of a finished adjustment, drawn as SVG from GET /jobs/{id}/results/geojson (CRS84):
// image footprints, control / check / tie points, check-point discrepancy arrows (exaggerated,
// the factor is shown) and a scale bar. No tile server, no external request: an equirectangular
// projection about the data's mean latitude (metres east = R cos(lat0) dlon, north = R dlat).
// Also the GIS downloads: GeoJSON and, per image, its RPC (GDAL _RPC.TXT and .RPB).
(() => {
  "use strict";
  const SVG = "http://www.w3.org/2000/svg";
  const R = 6371008.8; // mean Earth radius, m (display only)
  const W = 900, H = 560, PAD = 30;
  const COLORS = { control: "#1f6feb", check: "#d1242f", tie: "#6e7781", footprint: "#2da44e" };

  function svg(tag, attrs) {
    const node = document.createElementNS(SVG, tag);
    for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, String(v));
    return node;
  }

  function niceLength(m) {
    const p = 10 ** Math.floor(Math.log10(m));
    for (const f of [5, 2, 1]) if (f * p <= m) return f * p;
    return p;
  }

  function draw(geo) {
    const feats = geo.features || [];
    const coords = [];
    for (const f of feats) {
      if (f.geometry.type === "Polygon") coords.push(...f.geometry.coordinates[0]);
      else coords.push(f.geometry.coordinates);
    }
    const root = svg("svg", { id: "map-svg", viewBox: `0 0 ${W} ${H}`, width: "100%", role: "img", "aria-label": "map of the job" });
    if (!coords.length) return root;
    const lat0 = coords.reduce((s, c) => s + c[1], 0) / coords.length;
    const lon0 = coords.reduce((s, c) => s + c[0], 0) / coords.length;
    const k = Math.PI / 180;
    const toM = (c) => [R * Math.cos(lat0 * k) * (c[0] - lon0) * k, R * (c[1] - lat0) * k];
    const xy = coords.map(toM);
    const xs = xy.map((p) => p[0]), ys = xy.map((p) => p[1]);
    const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
    const scale = Math.min((W - 2 * PAD) / Math.max(x1 - x0, 1), (H - 2 * PAD - 30) / Math.max(y1 - y0, 1)); // px per m
    const px = (m) => [PAD + (m[0] - x0) * scale, H - PAD - 30 - (m[1] - y0) * scale];
    root.append(svg("rect", { x: 0, y: 0, width: W, height: H, fill: "#ffffff", stroke: "#d0d7de" }));
    const defs = svg("defs");
    const marker = svg("marker", { id: "map-arrow", viewBox: "0 0 10 10", refX: 9, refY: 5, markerWidth: 6, markerHeight: 6, orient: "auto-start-reverse" });
    marker.append(svg("path", { d: "M 0 0 L 10 5 L 0 10 z", fill: COLORS.check }));
    defs.append(marker);
    root.append(defs);
    const layer = (id) => { const g = svg("g", { id }); root.append(g); return g; };
    const gFoot = layer("map-footprints"), gArrows = layer("map-arrows"), gPoints = layer("map-points");
    for (const f of feats.filter((f) => f.properties.kind === "footprint")) {
      const pts = f.geometry.coordinates[0].map((c) => px(toM(c)).map((v) => v.toFixed(1)).join(",")).join(" ");
      const poly = svg("polygon", { points: pts, fill: COLORS.footprint, "fill-opacity": 0.08, stroke: COLORS.footprint, "stroke-width": 1.5, class: "footprint", "data-image": f.properties.image });
      const t = svg("title"); t.textContent = `image ${f.properties.image} (${f.properties.model})`;
      poly.append(t);
      gFoot.append(poly);
    }
    // discrepancy arrows: longest arrow about 12 % of the map width
    const checks = feats.filter((f) => f.properties.kind === "check" && f.properties.discrepancy_m && f.properties.discrepancy_m.e !== null);
    const longest = Math.max(0, ...checks.map((f) => Math.hypot(f.properties.discrepancy_m.e, f.properties.discrepancy_m.n)));
    const exaggeration = longest > 0 ? niceLength((0.12 * W) / (longest * scale)) : 1;
    for (const f of checks) {
      const a = px(toM(f.geometry.coordinates));
      const d = f.properties.discrepancy_m;
      const b = [a[0] + d.e * exaggeration * scale, a[1] - d.n * exaggeration * scale];
      gArrows.append(svg("line", { x1: a[0].toFixed(1), y1: a[1].toFixed(1), x2: b[0].toFixed(1), y2: b[1].toFixed(1), stroke: COLORS.check, "stroke-width": 1.5, "marker-end": "url(#map-arrow)", class: "discrepancy", "data-point": f.properties.id }));
    }
    for (const f of feats.filter((f) => f.geometry.type === "Point")) {
      const [cx, cy] = px(toM(f.geometry.coordinates));
      const kind = f.properties.kind;
      const c = svg("circle", { cx: cx.toFixed(1), cy: cy.toFixed(1), r: kind === "tie" ? 2.5 : 4, fill: COLORS[kind] || "#000", class: `point ${kind}`, "data-point": f.properties.id });
      const t = svg("title");
      const d = f.properties.discrepancy_m;
      t.textContent = `${kind} ${f.properties.id}` + (d && d.planimetric !== null ? `: discrepancy ${d.planimetric.toFixed(3)} m` : "")
        + (f.properties.rms_residual_px !== null ? `, image residual ${f.properties.rms_residual_px.toFixed(3)} px` : "");
      c.append(t);
      gPoints.append(c);
    }
    // scale bar (ground) and legend
    const barM = niceLength((0.25 * W) / scale);
    const bar = svg("g", { id: "map-scale" });
    const y = H - 18, x = PAD;
    bar.append(svg("line", { x1: x, y1: y, x2: x + barM * scale, y2: y, stroke: "#24292f", "stroke-width": 3 }));
    const label = svg("text", { x: x + barM * scale + 8, y: y + 4, "font-size": 12, fill: "#24292f" });
    label.textContent = barM >= 1000 ? `${barM / 1000} km` : `${barM} m`;
    bar.append(label);
    root.append(bar);
    const legend = svg("text", { id: "map-legend", x: W - PAD, y: H - 14, "text-anchor": "end", "font-size": 12, fill: "#57606a" });
    legend.textContent = `footprints (green) · control (blue) · check (red) · tie (grey)` + (checks.length ? ` · discrepancy arrows ×${exaggeration}` : "");
    root.append(legend);
    return root;
  }

  async function render(box, jobId, report, ui) {
    const id = encodeURIComponent(jobId);
    const stem = (report.job_name || "job").replace(/[^A-Za-z0-9._-]+/g, "_").slice(0, 60);
    const links = ui.el("div", { class: "downloads", id: "gis-downloads" }, ui.el("span", { class: "muted", text: "GIS:" }),
      ui.download(`jobs/${id}/results/geojson`, `${stem}.geojson`, "GeoJSON"));
    for (const im of report.images || []) {
      const img = encodeURIComponent(im.id);
      links.append(ui.download(`jobs/${id}/results/rpc/${img}?format=txt`, `${im.id}_RPC.TXT`, `${im.id} RPC`),
        ui.download(`jobs/${id}/results/rpc/${img}?format=rpb`, `${im.id}.RPB`, `${im.id} .RPB`));
    }
    const holder = ui.el("div", { id: "map", class: "map" }, ui.el("p", { class: "muted", text: "Loading the map…" }));
    box.append(ui.el("h3", { text: "Map" }), links, holder);
    try {
      const geo = await ui.api(`jobs/${id}/results/geojson`);
      while (holder.firstChild) holder.removeChild(holder.firstChild);
      holder.append(draw(geo));
    } catch (err) {
      while (holder.firstChild) holder.removeChild(holder.firstChild);
      holder.append(ui.el("p", { class: "error-box", text: `No map: ${err.message}` }));
    }
  }

  window.pbaMap = { render, draw };
})();
