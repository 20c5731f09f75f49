// The city map: the isopleth bands of /air/isopleths over a base map, each sky camera a
// marker labelled with its name and level (labels that would overlap hidden, worst air kept;
// a camera with no reading on the map grey, with why; each reference station a square with its
// name and measured PM2.5),
// a popup with its category, time, sky and last 24 h / 7 d; uncertainty and method toggles; a
// time slider over the last 24 h. Refreshes itself every minute.
(() => {
  const cfg = JSON.parse(document.getElementById("config").textContent);
  const colour = Object.fromEntries(cfg.categories.map((c) => [c.name, c.colour]));
  const $ = (id) => document.getElementById(id);
  const state = { method: "idw", layer: "levels", hours: 0, fitted: false };

  const map = L.map("map", { zoomControl: true }).setView([45.46, 9.19], 11);
  // the page sends no referrer (Referrer-Policy: no-referrer); tile servers such as
  // OpenStreetMap's ask for one, so the tiles alone send the site's origin, never the path
  L.tileLayer(cfg.tiles, { attribution: cfg.attribution, maxZoom: 19, referrerPolicy: "strict-origin" }).addTo(map);
  const ramp = ["#fde725", "#7ad151", "#22a884", "#2a788e", "#414487", "#440154", "#2d0a3e", "#1a0529"];
  const bands = L.geoJSON(null, {
    style: (f) => {
      const p = f.properties;
      const fill = p.category ? colour[p.category] : ramp[Math.min(bandIndex(p), ramp.length - 1)];
      return { fillColor: fill, fillOpacity: 0.55, color: "#555", weight: 0.6 };
    },
  }).addTo(map);
  const cameras = L.layerGroup().addTo(map);
  const monitors = L.layerGroup().addTo(map); // the reference stations, redrawn each time
  const markers = new Map();
  let uncertaintyEdges = [];

  function bandIndex(p) {
    const i = uncertaintyEdges.indexOf(p.uncertainty_min);
    return i < 0 ? 0 : i;
  }

  function legend(fc) {
    const ul = $("legend");
    ul.innerHTML = "";
    const rows = state.layer === "levels"
      ? cfg.categories.map((c) => [c.colour, `${c.name} ${c.lo}–${c.hi}`])
      : fc.features.map((f, i) => {
          const p = f.properties;
          const unit = p.unit === "m" ? " m" : " level";
          const label = p.uncertainty_max === null ? `≥ ${p.uncertainty_min}${unit}` : `${p.uncertainty_min}–${p.uncertainty_max}${unit}`;
          return [ramp[Math.min(i, ramp.length - 1)], label];
        });
    rows.push(["#e6e6e6", `no data: no camera within ${fc.max_distance_m / 1000} km`]);
    for (const [fill, text] of rows) {
      const li = document.createElement("li");
      li.innerHTML = `<span class="swatch" style="background:${fill}"></span>`;
      li.append(text);
      ul.append(li);
    }
  }

  function label(c) {
    return `${c.name || c.camera_id} ${Math.floor(c.level + 0.5)}`;
  }

  // Labels that would overlap one already shown are hidden; the worst air is placed first.
  function declutter() {
    // all writes, then all reads, then all writes: one layout, not one per label
    const shown = [...markers.values()].sort((a, b) => a.options.level - b.options.level);
    const els = shown.map((m) => m.getElement() && m.getElement().querySelector(".cam-label")).filter(Boolean);
    for (const el of els) el.classList.remove("hidden");
    const rects = els.map((el) => el.getBoundingClientRect());
    const placed = [];
    const hide = [];
    rects.forEach((r, i) => {
      const hit = placed.some((p) => r.left < p.right && r.right > p.left && r.top < p.bottom && r.bottom > p.top);
      if (hit) hide.push(els[i]);
      else placed.push(r);
    });
    for (const el of hide) el.classList.add("hidden");
  }

  async function chart(canvas, cameraId, days) {
    const since = new Date(Date.now() - days * 86400e3).toISOString();
    const q = new URLSearchParams({ camera_id: cameraId, aggregate: "hourly", since, limit: "200" });
    const rows = await (await fetch(`/air/readings?${q}`)).json();
    rows.sort((a, b) => a.start.localeCompare(b.start));
    const old = Chart.getChart(canvas);
    if (old) old.destroy();
    new Chart(canvas, {
      type: "line",
      data: {
        labels: rows.map((r) => new Date(r.start).toLocaleString([], days > 1 ? { month: "short", day: "numeric", hour: "2-digit" } : { hour: "2-digit", minute: "2-digit" })),
        datasets: [{ label: "mean level", data: rows.map((r) => r.mean_level), borderColor: "#12355b", pointRadius: 2 }],
      },
      options: { animation: false, scales: { y: { min: 1, max: 10 } }, plugins: { legend: { display: false } } },
    });
  }

  function popup(c) {
    const div = document.createElement("div");
    div.className = "popup";
    div.innerHTML = `<strong></strong><br><span class="cat"></span><br><small class="time"></small>
      <img alt="the camera's sky region"><div><button data-days="1">24 h</button> <button data-days="7">7 d</button></div><canvas></canvas>`;
    div.querySelector("strong").textContent = c.name || c.camera_id;
    div.querySelector(".cat").textContent = `${c.category}, level ${Math.floor(c.level + 0.5)}`;
    div.querySelector(".time").textContent = new Date(c.captured_at).toLocaleString();
    const sky = div.querySelector("img");
    sky.onerror = () => sky.remove(); // a camera with no sky region publishes no picture
    sky.src = `/air/cameras/${encodeURIComponent(c.camera_id)}/sky.jpg`;
    const canvas = div.querySelector("canvas");
    for (const b of div.querySelectorAll("button")) b.onclick = () => chart(canvas, c.camera_id, Number(b.dataset.days));
    setTimeout(() => chart(canvas, c.camera_id, 1), 0);
    return div;
  }

  // Every sky camera in service (/air/latest, page by page; what came before a failure).
  async function everyCamera() {
    const every = [];
    try {
      for (let offset = 0; ; offset += 1000) {
        const r = await fetch(`/air/latest?limit=1000&offset=${offset}`, { cache: "no-store" });
        if (!r.ok) return every;
        const page = await r.json();
        every.push(...page);
        if (page.length < 1000) return every;
      }
    } catch (e) {
      return every;
    }
  }

  // Those cameras this map has no reading of (new, quiet, or unsure of the air): a grey marker
  // each, so that a camera never vanishes from the city's map. Marked as seen.
  function quiet(every, seen) {
    const silent = every.filter((c) => !seen.has(c.camera_id) && c.lat !== null && c.lon !== null);
    for (const c of silent) {
      seen.add(c.camera_id);
      const key = `silent:${c.lat},${c.lon},${c.name},${c.captured_at},${c.reason}`;
      let m = markers.get(c.camera_id);
      if (m && m.options.key === key) continue;
      if (m) cameras.removeLayer(m);
      const html = `<span class="dot"></span><span class="cam-label"></span>`;
      // level 11, past the best air: declutter places its label last
      m = L.marker([c.lat, c.lon], { icon: L.divIcon({ className: "cam silent", html, iconSize: null }), key, level: 11, camera: c });
      m.bindPopup(() => quietPopup(c), { maxWidth: 300 });
      markers.set(c.camera_id, m);
      cameras.addLayer(m);
      m.getElement().querySelector(".cam-label").textContent = `${c.name || c.camera_id} –`;
    }
    return silent;
  }

  function quietPopup(c) {
    const div = document.createElement("div");
    div.className = "popup";
    div.innerHTML = `<strong></strong><br><span class="cat">No reading on this map</span><br><small class="why"></small>`;
    div.querySelector("strong").textContent = c.name || c.camera_id;
    const last = c.captured_at ? `latest frame ${new Date(c.captured_at).toLocaleString()}` : "";
    div.querySelector(".why").textContent = [c.message, c.reason, last].filter(Boolean).join(" · ");
    return div;
  }

  // Take off the markers of cameras not `seen`; `keepSilent`: the grey ones stay until the
  // list of every camera has said whether they are still without a reading.
  function prune(seen, keepSilent) {
    for (const [id, m] of markers) {
      if (seen.has(id) || (keepSilent && m.options.key.startsWith("silent:"))) continue;
      cameras.removeLayer(m);
      markers.delete(id);
    }
  }

  async function refresh() {
    const q = new URLSearchParams({ method: state.method, layer: state.layer });
    if (state.fitted) {
      // the bands over what is in view (clipped to the globe), once the cameras are in view
      const b = map.getBounds();
      const box = [Math.max(b.getWest(), -180), Math.max(b.getSouth(), -90), Math.min(b.getEast(), 180), Math.min(b.getNorth(), 90)];
      q.set("bbox", box.map((v) => v.toFixed(5)).join(","));
    }
    if (state.hours < 0) q.set("at", new Date(Date.now() + state.hours * 3600e3).toISOString());
    const every = everyCamera(); // asked for beside the map, placed after it
    let fc;
    try {
      const r = await fetch(`/air/isopleths?${q}`, { cache: "no-store" });
      fc = await r.json();
      if (!r.ok) throw new Error(fc.detail || `HTTP ${r.status}`);
    } catch (e) {
      $("status").textContent = `The map could not be loaded: ${e.message}`;
      return;
    }
    uncertaintyEdges = fc.features.map((f) => f.properties.uncertainty_min);
    bands.clearLayers();
    bands.addData(fc.features);
    // each camera a marker whose icon is its dot and label (Leaflet's tooltips measure
    // themselves as they open, a layout each: 2.2 s for a thousand cameras); kept between
    // refreshes and changed only where its reading changed
    const seen = new Set();
    for (const c of fc.cameras) {
      seen.add(c.camera_id);
      const key = `${c.lat},${c.lon},${c.category},${label(c)}`;
      let m = markers.get(c.camera_id);
      if (m && m.options.key === key) {
        m.options.camera = c;
        continue;
      }
      if (m) cameras.removeLayer(m);
      const html = `<span class="dot" style="background:${colour[c.category]}"></span><span class="cam-label"></span>`;
      m = L.marker([c.lat, c.lon], { icon: L.divIcon({ className: "cam", html, iconSize: null }), key, level: c.level, camera: c });
      m.bindPopup(() => popup(m.options.camera), { maxWidth: 300 });
      markers.set(c.camera_id, m);
      cameras.addLayer(m);
      m.getElement().querySelector(".cam-label").textContent = label(c);
    }
    prune(seen, true);
    // each reference station a square marker with its name and measured value (text, never
    // markup: a station's name is the city's to choose)
    monitors.clearLayers();
    for (const s of fc.stations || []) {
      const html = `<span class="square" style="background:${colour[s.category]}"></span><span class="cam-label"></span>`;
      const m = L.marker([s.lat, s.lon], { icon: L.divIcon({ className: "cam station", html, iconSize: null }) });
      monitors.addLayer(m);
      m.getElement().querySelector(".cam-label").textContent =
        `${s.name || s.station_id}: ${Math.round(s.value)} µg/m³ (station)`;
    }
    let view = null;
    if (!state.fitted && fc.bbox) {
      state.fitted = true;
      view = L.latLngBounds([[fc.bbox[1], fc.bbox[0]], [fc.bbox[3], fc.bbox[2]]]);
      map.fitBounds(view, { padding: [30, 30] });
    }
    legend(fc);
    const notes = [`${fc.cameras.length} cameras, ${(fc.stations || []).length} stations, ${fc.method}, map of ${new Date(fc.at).toLocaleString()}`];
    if (fc.empty_reason) notes.push(`Nothing drawn: ${fc.empty_reason}.`);
    notes.push(...fc.warnings);
    $("status").textContent = notes.join(" ");
    declutter();
    document.body.dataset.maps = String(Number(document.body.dataset.maps || 0) + 1);

    // then the cameras without a reading on this map, not holding the map up (the list of
    // every camera takes as long as the map with a thousand of them)
    const silent = quiet(await every, seen);
    prune(seen, false);
    const shown = view || map.getBounds(); // the view just fitted, though still animating
    const outside = silent.filter((c) => !shown.contains([c.lat, c.lon]));
    if ((view || !state.fitted) && outside.length) {
      // the first view holds every camera: the city is where its cameras are
      state.fitted = true;
      const all = L.latLngBounds(silent.map((c) => [c.lat, c.lon]));
      if (view) all.extend(view);
      map.fitBounds(all, { padding: [30, 30], maxZoom: 14 });
    }
    if (silent.length) notes.splice(1, 0, `${silent.length} more without a reading on this map (grey).`);
    $("status").textContent = notes.join(" ");
    declutter();
    document.body.dataset.quiet = String(Number(document.body.dataset.quiet || 0) + 1);
  }

  let moved = null;
  map.on("zoomend moveend", () => {
    declutter();
    clearTimeout(moved);
    if (state.fitted) moved = setTimeout(refresh, 400); // the bands of the new view
  });
  $("method").onchange = (e) => { state.method = e.target.value; refresh(); };
  $("uncertainty").onchange = (e) => { state.layer = e.target.checked ? "uncertainty" : "levels"; refresh(); };
  $("hours").oninput = (e) => {
    state.hours = Number(e.target.value);
    $("when").textContent = state.hours === 0 ? "now" : new Date(Date.now() + state.hours * 3600e3).toLocaleString([], { hour: "2-digit", minute: "2-digit" });
  };
  $("hours").onchange = refresh;
  refresh();
  setInterval(refresh, 60000);
})();
