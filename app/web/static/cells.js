// Robot cells: each calibration by name with its per-view error (fitted and held out), the
// rigs with their cameras (and the robot's base) in 3-D, and the outline tool (a photo in,
// the conditioned image, the sides and numbered corners out).
(() => {
  const $ = (id) => document.getElementById(id);
  const KINDS = { single: "camera", stereo: "stereo pair", hand_eye: "hand-eye" };

  async function json(path) {
    const r = await Auth.api(path);
    if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
    return r.json();
  }

  // What a calibration says in one line: its name, kind, fit and held-out errors.
  function summary(c) {
    const when = new Date(c.created_at).toLocaleString();
    const name = c.name || `${KINDS[c.kind] || c.kind} calibration of ${when}`;
    const parts = [name, KINDS[c.kind] || c.kind];
    const cam = c.kind === "stereo" ? c.left : c;
    if (c.rms_px != null) parts.push(`RMS ${Number(c.rms_px).toFixed(3)} px`);
    if (c.loo_rms_px != null) parts.push(`held out ${Number(c.loo_rms_px).toFixed(3)} px`);
    if (c.kind === "hand_eye") {
      parts.push(`${Number(c.rms_mm).toFixed(2)} mm, ${Number(c.rms_deg).toFixed(2)}°`);
      const m = c.camera_to_base || c.camera_to_flange;
      const where = c.camera_to_base ? "base" : "flange";
      parts.push(`camera at (${m.slice(0, 3).map((row) => row[3].toFixed(3)).join(", ")}) m in the ${where}`);
    } else if (cam && cam.pixel_sigma_px) {
      parts.push(`a pixel's uncertainty ${cam.pixel_sigma_px.centre.toFixed(2)} px at the centre, ${cam.pixel_sigma_px.corner.toFixed(2)} px at the corner`);
    }
    if (c.name) parts.push(when);
    return parts.join(" · ");
  }

  // Bars per view: the fit's reprojection RMS, beside it each view held out, and the
  // held-out RMS over all views as a line.
  function chart(canvas, c) {
    const cam = c.kind === "stereo" ? c.left : c;
    const views = c.kind === "hand_eye" ? c.per_view.map((v) => v.file) : cam.views_used || [];
    const fit = c.kind === "hand_eye" ? c.per_view.map((v) => v.rms_px) : cam.per_view_rms_px || [];
    const held = c.kind === "hand_eye" ? [] : cam.per_view_loo_px || [];
    const datasets = [{ label: "fitted [px]", data: fit, backgroundColor: "#2c7bb6" }];
    if (held.length) datasets.push({ label: "held out [px]", data: held, backgroundColor: "#fdae61" });
    if (cam.loo_rms_px != null) {
      datasets.push({ type: "line", label: `held-out RMS ${cam.loo_rms_px.toFixed(3)} px`, data: views.map(() => cam.loo_rms_px), borderColor: "#d7191c", pointRadius: 0, borderDash: [6, 4] });
    }
    return new Chart(canvas, {
      type: "bar",
      data: { labels: views, datasets },
      options: {
        animation: false, maintainAspectRatio: false,
        scales: {
          x: { title: { display: true, text: c.kind === "stereo" ? "view (left camera)" : "view" } },
          y: { beginAtZero: true, title: { display: true, text: "reprojection error [px]" } },
        },
      },
    });
  }

  async function calibrations() {
    const list = await json("/calibrations?limit=50");
    const box = $("calibrations");
    box.replaceChildren();
    if (!list.length) {
      const p = document.createElement("p");
      p.textContent = "No calibrations yet (POST /calibrations).";
      box.append(p);
    }
    for (const c of list) {
      const div = document.createElement("div");
      div.className = "calibration";
      div.dataset.id = c.id;
      const title = document.createElement("p");
      title.className = "calibration-title";
      title.textContent = summary(c);
      const wrap = document.createElement("div");
      wrap.className = "chart";
      const canvas = document.createElement("canvas");
      wrap.append(canvas);
      div.append(title, wrap);
      box.append(div);
      chart(canvas, c);
    }
  }

  // The rig's cameras seen from above and aside at once (an isometric drawing): each lens
  // centre −Rᵀt with its viewing direction, and the robot's base where a hand-eye places it.
  function drawRig(canvas, rig) {
    const cams = (rig.spec.cameras || []).map((c, i) => {
      const R = c.R, t = c.t;
      const centre = [0, 1, 2].map((k) => -(R[0][k] * t[0] + R[1][k] * t[1] + R[2][k] * t[2]));
      return { label: `camera ${i}`, at: centre, look: [R[2][0], R[2][1], R[2][2]] };
    });
    const things = cams.map((c) => ({ label: c.label, at: c.at, look: c.look }));
    const robot = rig.spec.robot;
    if (robot) {
      // the base's origin in the rig's frame: M⁻¹ · 0 = −Rᵀ t, over the rig's unit
      const M = robot.rig_to_base, u = robot.rig_unit_m;
      const origin = [0, 1, 2].map((k) => -(M[0][k] * M[0][3] + M[1][k] * M[1][3] + M[2][k] * M[2][3]) / u);
      things.push({ label: "robot base", at: origin, base: true });
    }
    canvas.dataset.cameras = String(cams.length);
    canvas.dataset.robot = robot ? "yes" : "no";
    const ctx = canvas.getContext("2d");
    const W = canvas.width, H = canvas.height;
    ctx.clearRect(0, 0, W, H);
    if (!things.length) return;
    const iso = ([x, y, z]) => [(x - z) * Math.cos(Math.PI / 6), (x + z) * Math.sin(Math.PI / 6) + y];
    const spread = Math.max(1e-9, ...things.flatMap((a) => things.map((b) => Math.hypot(...a.at.map((v, k) => v - b.at[k])))));
    const arrow = spread / 4;
    const pts = things.flatMap((a) => [iso(a.at), ...(a.look ? [iso(a.at.map((v, k) => v + arrow * a.look[k]))] : [])]);
    const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
    const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
    const scale = Math.min((W - 120) / Math.max(x1 - x0, 1e-9), (H - 60) / Math.max(y1 - y0, 1e-9));
    const px = (p) => { const [a, b] = iso(p); return [60 + (a - x0) * scale, 30 + (b - y0) * scale]; };
    ctx.font = "12px sans-serif";
    for (const a of things) {
      const [u, v] = px(a.at);
      ctx.fillStyle = a.base ? "#1a9641" : "#2c7bb6";
      ctx.strokeStyle = ctx.fillStyle;
      if (a.base) ctx.fillRect(u - 6, v - 6, 12, 12);
      else { ctx.beginPath(); ctx.arc(u, v, 5, 0, 2 * Math.PI); ctx.fill(); }
      if (a.look) {
        const [p, q] = px(a.at.map((w, k) => w + arrow * a.look[k]));
        ctx.beginPath(); ctx.moveTo(u, v); ctx.lineTo(p, q); ctx.stroke();
      }
      ctx.fillStyle = "#222";
      ctx.fillText(a.label, u + 8, v - 8);
    }
  }

  async function rigs() {
    const list = await json("/rigs?limit=100");
    const box = $("rigs");
    box.replaceChildren();
    if (!list.length) {
      const p = document.createElement("p");
      p.textContent = "No rigs yet (POST /rigs).";
      box.append(p);
    }
    for (const rig of list) {
      const fig = document.createElement("figure");
      fig.className = "rig";
      fig.dataset.id = rig.id;
      const canvas = document.createElement("canvas");
      canvas.width = 420;
      canvas.height = 260;
      const cap = document.createElement("figcaption");
      const n = rig.kind === "cross" ? 4 : (rig.spec.cameras || []).length;
      const robot = rig.spec.robot ? `, in the robot's base by hand-eye calibration ${rig.spec.robot.hand_eye_id}` : "";
      cap.textContent = `${rig.id}: ${rig.kind === "cross" ? "the 4-camera cross" : `${n} calibrated cameras`}${robot}`;
      fig.append(canvas, cap);
      box.append(fig);
      if (rig.kind !== "cross") drawRig(canvas, rig);
    }
  }

  async function load() {
    await Promise.all([calibrations(), rigs()]);
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
    body.replaceChildren();
    const answer = await found.json();
    if (!found.ok) {
      $("outline-error").textContent = answer.detail || `HTTP ${found.status}`;
      return;
    }
    answer.corners.forEach(([x, y], i) => {
      const tr = document.createElement("tr");
      for (const v of [String(i + 1), x.toFixed(2), y.toFixed(2)]) {
        const td = document.createElement("td");
        td.textContent = v;
        tr.append(td);
      }
      body.append(tr);
    });
  });

  Auth.start(load);
})();
