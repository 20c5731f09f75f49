// The solar farm board: panels as a grid coloured by state, open cleaning tasks with their
// robots and leases, a panel's soiling trend (its history) and its last frame's region.
(() => {
  const $ = (id) => document.getElementById(id);
  const NAMES = { clean: "clean", needs_cleaning: "needs cleaning", cleaning: "being cleaned", unknown: "unknown", no_baseline: "no baseline" };

  async function json(path) {
    const r = await Auth.api(path);
    if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
    return r.json();
  }

  async function detail(panel) {
    $("detail").hidden = false;
    $("detail-title").textContent = `${panel.name || panel.id}: ${NAMES[panel.state] || panel.state}`;
    const status = await json(`/panels/${encodeURIComponent(panel.id)}/status`);
    const last = status.last_verdict;
    // the 14 days up to the panel's last frame (a panel gone quiet shows its last weeks)
    const end = last && last.captured_at ? new Date(last.captured_at) : new Date();
    const since = new Date(end.getTime() - 14 * 86400e3).toISOString();
    const until = new Date(end.getTime() + 86400e3).toISOString();
    const q = new URLSearchParams({ bucket: "day", since, until });
    const history = await json(`/panels/${encodeURIComponent(panel.id)}/history?${q}`);
    const old = Chart.getChart($("trend"));
    if (old) old.destroy();
    new Chart($("trend"), {
      type: "line",
      data: {
        labels: history.map((h) => new Date(h.start).toLocaleDateString()),
        datasets: [
          { label: "share judged dirty", data: history.map((h) => (h.clean + h.dirty ? h.dirty / (h.clean + h.dirty) : null)), borderColor: "#d7191c", yAxisID: "y" },
          { label: "mean T²", data: history.map((h) => h.t2_mean), borderColor: "#2c7bb6", yAxisID: "t2" },
        ],
      },
      options: { animation: false, maintainAspectRatio: false, scales: { y: { min: 0, max: 1, position: "left" }, t2: { position: "right" } } },
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
