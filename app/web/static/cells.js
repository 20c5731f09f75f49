// Robot cells: each calibration's per-view reprojection error; the outline tool (a photo in,
// the conditioned image, the sides and numbered corners out).
(() => {
  const $ = (id) => document.getElementById(id);

  async function load() {
    const r = await Auth.api("/calibrations?limit=50");
    if (!r.ok) throw new Error(`HTTP ${r.status}`);
    const calibrations = await r.json();
    const box = $("calibrations");
    box.innerHTML = calibrations.length ? "" : "<p>No calibrations yet (POST /calibrations).</p>";
    for (const c of calibrations) {
      const div = document.createElement("div");
      div.className = "calibration";
      const title = document.createElement("p");
      const rms = c.rms_px !== undefined ? `RMS ${Number(c.rms_px).toFixed(3)} px` : "";
      title.textContent = `${c.id} · ${c.kind || "camera"} · ${rms} · ${new Date(c.created_at).toLocaleString()}`;
      const canvas = document.createElement("canvas");
      canvas.height = 120;
      div.append(title, canvas);
      box.append(div);
      const per = c.per_view_rms_px || [];
      new Chart(canvas, {
        type: "bar",
        data: { labels: per.map((_, i) => `view ${i + 1}`), datasets: [{ label: "reprojection RMS [px]", data: per, backgroundColor: "#2c7bb6" }] },
        options: { animation: false, plugins: { legend: { display: false } }, scales: { y: { beginAtZero: true, title: { display: true, text: "px" } } } },
      });
    }
  }

  $("outline-form").addEventListener("submit", async (e) => {
    e.preventDefault();
    $("outline-error").textContent = "";
    const file = $("photo").files[0];
    if (!file) return;
    const form = () => { const f = new FormData(); f.append("file", file); return f; };
    const [enhanced, drawn, found] = await Promise.all([
      Auth.api("/vision/enhance", { method: "POST", body: form() }),
      Auth.api("/vision/outline.png", { method: "POST", body: form() }),
      Auth.api("/vision/outline", { method: "POST", body: form() }),
    ]);
    if (enhanced.ok) $("conditioned").src = URL.createObjectURL(await enhanced.blob());
    if (drawn.ok) $("outlined").src = URL.createObjectURL(await drawn.blob());
    const body = $("corners").querySelector("tbody");
    body.innerHTML = "";
    const answer = await found.json();
    if (!found.ok) {
      $("outline-error").textContent = answer.detail || `HTTP ${found.status}`;
      return;
    }
    answer.corners.forEach(([x, y], i) => {
      const tr = document.createElement("tr");
      tr.innerHTML = `<td>${i + 1}</td><td>${x.toFixed(2)}</td><td>${y.toFixed(2)}</td>`;
      body.append(tr);
    });
  });

  Auth.start(load);
})();
