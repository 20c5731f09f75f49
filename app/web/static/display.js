// The screen below a sky camera: today's category, large, with how sure the camera is, its
// estimate and range, the time and the 1–10 scale. Only what the service says in public words
// (its message): never an API's. With ?at= in the page's address, the screen as it was then.
// Refreshes itself.
(() => {
  const cfg = JSON.parse(document.getElementById("config").textContent);
  const colour = Object.fromEntries(cfg.categories.map((c) => [c.name, c.colour]));
  const $ = (id) => document.getElementById(id);
  const when = (iso) => new Date(iso).toLocaleString([], { dateStyle: "medium", timeStyle: "short" });
  const UNITS = { pm25: ["PM2.5", "µg/m³"], aqi: ["AQI", ""], level: ["level", ""] };
  const round = (v) => (v >= 10 ? Math.round(v) : Math.round(v * 10) / 10);

  function estimateWords(e) {
    if (!e || e.value === null) return "";
    const [name, unit] = UNITS[e.unit] || [e.unit, ""];
    const range = e.low !== null && e.high !== null ? `, ${round(e.low)}–${round(e.high)}` : "";
    return `${name} about ${round(e.value)}${unit ? " " + unit : ""}${range}`;
  }

  function scale(level) {
    const cells = $("scale").children;
    for (let i = 0; i < cells.length; i++) {
      cells[i].classList.toggle("on", level !== null && Number(cells[i].dataset.level) === level);
    }
  }

  function show(latest) {
    $("name").textContent = latest.name || cfg.name;
    $("headline").textContent = latest.message || "Air quality not measured here yet";
    const speaks = latest.current && latest.level !== null && latest.category;
    if (speaks) {
      $("level").textContent = String(latest.level);
      $("level").style.color = colour[latest.category];
      $("estimate").textContent = estimateWords(latest.smoothed_estimate);
      $("time").textContent = when(latest.captured_at);
      document.body.dataset.state = "current";
    } else {
      $("level").textContent = "–";
      $("level").style.color = "#888";
      $("estimate").textContent = "";
      $("time").textContent = latest.captured_at ? `last reading ${when(latest.captured_at)}` : "";
      document.body.dataset.state = "none";
    }
    scale(speaks ? latest.level : null);
  }

  async function refresh() {
    const at = cfg.at ? `?at=${encodeURIComponent(cfg.at)}` : "";
    try {
      const r = await fetch(`/air/cameras/${encodeURIComponent(cfg.camera_id)}/latest${at}`, { cache: "no-store" });
      if (!r.ok) throw new Error(`HTTP ${r.status}`);
      show(await r.json());
    } catch (e) {
      show({ current: false, level: null, name: cfg.name, message: "The air-quality service cannot be reached" });
    }
  }
  refresh();
  if (!cfg.at) setInterval(refresh, 30000);
})();
