// The screen below a sky camera: today's category, large; "No current reading" when the
// camera's latest reading is stale or it is not sure. Refreshes itself.
(() => {
  const cfg = JSON.parse(document.getElementById("config").textContent);
  const colour = Object.fromEntries(cfg.categories.map((c) => [c.name, c.colour]));
  const $ = (id) => document.getElementById(id);
  const when = (iso) => new Date(iso).toLocaleString([], { dateStyle: "medium", timeStyle: "short" });

  function show(latest) {
    $("name").textContent = latest.name || cfg.name;
    if (latest.current && latest.level !== null && latest.category) {
      $("headline").textContent = `Today's Air Quality is ${latest.category}`;
      $("level").textContent = String(latest.level);
      $("level").style.color = colour[latest.category];
      $("time").textContent = when(latest.captured_at);
      $("note").textContent = "Air quality 1 (Very Poor) to 10 (Very Good)";
      document.body.dataset.state = "current";
    } else {
      $("headline").textContent = "No current reading";
      $("level").textContent = "–";
      $("level").style.color = "#888";
      $("time").textContent = latest.captured_at ? `last reading ${when(latest.captured_at)}` : "no readings yet";
      $("note").textContent = latest.message || latest.reason || "";
      document.body.dataset.state = "none";
    }
  }

  async function refresh() {
    try {
      const r = await fetch(`/air/cameras/${encodeURIComponent(cfg.camera_id)}/latest`, { cache: "no-store" });
      if (!r.ok) throw new Error(`HTTP ${r.status}`);
      show(await r.json());
    } catch (e) {
      show({ current: false, level: null, name: cfg.name, reason: "the service cannot be reached" });
    }
  }
  refresh();
  setInterval(refresh, 30000);
})();
