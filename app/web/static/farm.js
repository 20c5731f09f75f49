// The solar farm board: panels as a grid coloured by state, open cleaning tasks with their
// robots and leases, a panel's soiling from its camera and its output side by side, and its
// last frame's region.
(() => {
  const $ = (id) => document.getElementById(id);
  const NAMES = { clean: "clean", needs_cleaning: "needs cleaning", cleaning: "being cleaned", unknown: "unknown", no_baseline: "no baseline" };

  async function json(path) {
    const r = await Auth.api(path);
    if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
    return r.json();
  }

  // What the output says of the panel, in words: the ratio with its range, the loss, whether
  // cleaning pays, and whether the camera and the output agree.
  function output(soiling, last) {
    if (soiling.soiling_ratio == null) return `Output: ${soiling.reason || "none stored"}.`;
    const pct = (x) => `${(100 * x).toFixed(1)} %`;
    const since = soiling.last_cleaning ? `the cleaning of ${soiling.last_cleaning}` : `${soiling.intervals[soiling.intervals.length - 1].start} (the first day of output)`;
    const parts = [
      `Output on ${soiling.as_of}: ${pct(soiling.soiling_ratio)} of clean (95 % range ${pct(soiling.low)}–${pct(soiling.high)}),`,
      `losing ${soiling.loss_kwh_per_day.toFixed(2)} kWh a day, ${soiling.loss_since_cleaning_kwh.toFixed(1)} kWh since ${since}.`,
    ];
    const rec = soiling.recommendation;
    if (rec) parts.push(rec.clean ? `Cleaning pays now: ${rec.reason}.` : `Cleaning does not pay yet: ${rec.reason}.`);
    else if (soiling.reason) parts.push(`${soiling.reason}.`);
    // the camera's last word against the output's: soiled when even the range's top is below 97 %
    const soiled = soiling.high < 0.97, clean = soiling.low > 0.97;
    if (last && last.clean != null && (soiled || clean)) {
      const agree = (last.clean === false) === soiled;
      parts.push(`The camera says ${last.clean ? "clean" : "dirty"}; the output ${agree ? "agrees" : "disagrees"}.`);
    }
    return parts.join(" ");
  }

  async function detail(panel) {
    $("detail").hidden = false;
    $("detail-title").textContent = `${panel.name || panel.id}: ${NAMES[panel.state] || panel.state}`;
    const id = encodeURIComponent(panel.id);
    const [status, soiling] = await Promise.all([json(`/panels/${id}/status`), json(`/panels/${id}/soiling`)]);
    const last = status.last_verdict;
    $("output").textContent = output(soiling, last);
    // the 90 days up to the panel's last frame or day of output (a panel gone quiet shows its
    // last months)
    const ends = [last && last.captured_at, soiling.as_of].filter(Boolean).map((t) => new Date(t).getTime());
    const end = ends.length ? Math.max(...ends) : Date.now();
    const since = new Date(end - 90 * 86400e3).toISOString();
    const until = new Date(end + 86400e3).toISOString();
    const q = new URLSearchParams({ bucket: "day", since, until });
    const history = await json(`/panels/${id}/history?${q}`);
    const old = Chart.getChart($("trend"));
    if (old) old.destroy();
    new Chart($("trend"), {
      type: "line",
      data: {
        labels: history.map((h) => h.start.slice(0, 10)),
        datasets: [
          { label: "95 % range", data: history.map((h) => h.soiling_low), borderColor: "rgba(44,123,182,0.2)", pointRadius: 0, yAxisID: "y" },
          { label: "95 % range (top)", data: history.map((h) => h.soiling_high), borderColor: "rgba(44,123,182,0.2)", backgroundColor: "rgba(44,123,182,0.2)", fill: "-1", pointRadius: 0, yAxisID: "y" },
          { label: "soiling ratio (fit)", data: history.map((h) => h.soiling_ratio), borderColor: "#2c7bb6", pointRadius: 0, yAxisID: "y" },
          { label: "performance index", data: history.map((h) => h.performance_index), borderColor: "#999", showLine: false, pointRadius: 2, yAxisID: "y" },
          { label: "cleaning", data: history.map((h) => (h.cleaned ? 1.02 : null)), borderColor: "#1a9641", backgroundColor: "#1a9641", showLine: false, pointStyle: "triangle", pointRadius: 7, yAxisID: "y" },
          { label: "share of frames judged dirty (camera)", data: history.map((h) => (h.clean + h.dirty ? h.dirty / (h.clean + h.dirty) : null)), borderColor: "#d7191c", backgroundColor: "#d7191c", showLine: false, pointRadius: 3, yAxisID: "camera" },
        ],
      },
      options: {
        animation: false, maintainAspectRatio: false, spanGaps: false,
        plugins: { legend: { labels: { filter: (item) => !item.text.endsWith("(top)") } } },
        scales: {
          y: { position: "left", suggestedMin: 0.7, suggestedMax: 1.05, title: { display: true, text: "output / clean output" } },
          camera: { position: "right", min: 0, max: 1, grid: { drawOnChartArea: false }, title: { display: true, text: "camera: share judged dirty" } },
        },
      },
    });
    const frame = last && last.frame_id;
    $("thumb").hidden = !frame;
    if (frame) {
      const r = await Auth.api(`/frames/${encodeURIComponent(frame)}/region.jpg`);
      if (r.ok) $("thumb").src = URL.createObjectURL(await r.blob());
    }
  }

  // What judges the panels without a baseline of their own, and how well it did on photos it
  // did not learn from: on panels it never saw when trained with groups, else on photos left out
  // one at a time, which flatters it when several photos show one panel.
  async function fleet() {
    const r = await Auth.api("/fleet/model");
    if (r.status === 404) return "No fleet model: panels without a baseline of their own are not judged.";
    if (!r.ok) throw new Error(`/fleet/model: HTTP ${r.status}`);
    const m = await r.json();
    const photos = [`${m.n_clean} clean`, `${m.n_dirty} needing cleaning`, ...(m.n_snow ? [`${m.n_snow} under snow`] : [])].join(", ");
    const of = m.n_groups ? ` of ${m.n_groups} panels` : "";
    const where = m.n_groups ? "on panels it never saw" : "on photos it did not learn from (high if several show one panel: train with groups)";
    const range = m.cv_low == null ? "" : ` (95 % interval ${m.cv_low.toFixed(2)}–${m.cv_high.toFixed(2)})`;
    const score = m.cv_balanced_accuracy == null ? "" : `; balanced accuracy ${m.cv_balanced_accuracy.toFixed(2)}${range} ${where}`;
    const sure = m.cv_sure_balanced_accuracy == null ? "" : ` It answers ${Math.round(100 * m.cv_answered)} % of frames, those at ${m.cv_sure_balanced_accuracy.toFixed(2)}; the others it lists below as not sure.`;
    const farm = !m.n_farm ? "" : m.cv_without_farm == null
      ? ` ${m.n_farm} of its photos are frames the farm labelled.`
      : ` ${m.n_farm} of its photos are frames the farm labelled: without them it would score ${m.cv_without_farm.toFixed(2)} on the same panels.`;
    return `Fleet model of ${new Date(m.created_at).toLocaleDateString()}: ${photos} photos${of}${score}.${sure}${farm}`;
  }

  // The frames the fleet model would not judge, to label: what the farm teaches the model.
  // A viewer sees them; only the admin's labels are taken (a viewer is told so).
  const LABELS = ["clean", "dust", "bird_drop", "snow"];

  async function doubts() {
    const [list, given] = await Promise.all([json("/fleet/doubts?limit=12"), json("/fleet/labels")]);
    $("labels").textContent = given.total
      ? `The farm has labelled ${given.total} frames: ${LABELS.map((l) => `${l.replace("_", " ")} ${given.counts[l]}`).join(", ")}.`
      : "The farm has labelled no frames yet.";
    const box = $("doubts");
    box.replaceChildren();
    if (!list.length) {
      const p = document.createElement("p");
      p.textContent = "None: the model judged every frame it was given.";
      box.append(p);
    }
    for (const d of list) {
      const fig = document.createElement("figure");
      fig.className = "doubt";
      fig.dataset.frame = d.frame_id;
      const img = document.createElement("img");
      img.alt = `frame ${d.frame_id}`;
      const cap = document.createElement("figcaption");
      cap.textContent = `${d.panel_id || d.camera_id}, ${new Date(d.captured_at).toLocaleString()}: ${d.reason || "doubted"}`;
      fig.append(img, cap);
      for (const label of LABELS) {
        const b = document.createElement("button");
        b.type = "button";
        b.textContent = label.replace("_", " ");
        b.onclick = async () => {
          const r = await Auth.api(`/fleet/labels/${encodeURIComponent(d.frame_id)}`, {
            method: "PUT", headers: { "Content-Type": "application/json" }, body: JSON.stringify({ label }),
          });
          if (r.ok) return doubts();
          cap.textContent = r.status === 403 ? "Only the admin's labels are taken (this token reads only)." : `Not labelled: HTTP ${r.status}`;
        };
        fig.append(b);
      }
      box.append(fig);
      Auth.api(d.image).then(async (r) => { if (r.ok) img.src = URL.createObjectURL(await r.blob()); });
    }
  }

  async function load() {
    const [panels, counts, tasks, model] = await Promise.all([
      json("/panels?limit=1000"),
      json("/panel-states"),
      json("/cleaning/tasks?limit=500"),
      fleet(),
      doubts(),
    ]);
    $("fleet").textContent = model;
    $("counts").textContent = Object.entries(counts.states).map(([k, v]) => `${NAMES[k] || k}: ${v}`).join(" · ") + ` (of ${counts.total})`;
    const grid = $("panels");
    grid.innerHTML = "";
    for (const p of panels) {
      const tile = document.createElement("button");
      tile.type = "button";
      tile.className = `tile ${p.state}`;
      tile.dataset.panel = p.id;
      // the cameras' latest word: a clean panel whose last frames said dirty shows how near
      // the trigger it is ("dirty 2/3"), not just "clean"
      const streak = p.dirty_streak > 0 && ["clean", "unknown"].includes(p.state) ? ` · dirty ${p.dirty_streak}/${p.streak_needed}` : "";
      const doubt = p.doubted ? " · latest frame doubted" : "";
      tile.textContent = `${p.name || p.id} — ${NAMES[p.state] || p.state}${streak}${doubt}`;
      tile.onclick = () => detail(p);
      grid.append(tile);
    }
    const body = $("tasks").querySelector("tbody");
    body.innerHTML = "";
    const open = tasks.filter((t) => ["pending", "claimed"].includes(t.status));
    for (const t of open) {
      const tr = document.createElement("tr");
      for (const v of [t.panel_id, t.status, t.robot_id || "—", t.lease_expires_at ? new Date(t.lease_expires_at).toLocaleString() : "—", new Date(t.created_at).toLocaleString()]) {
        const td = document.createElement("td");
        td.textContent = v;
        tr.append(td);
      }
      body.append(tr);
    }
  }

  Auth.start(load);
  setInterval(() => { if (Auth.token() && !$("board").hidden) load().catch(() => {}); }, 60000);
})();
