// Drawing one frame of an env on a canvas: world metres to pixels through a view (centre, scale).

/** Colour of a risk weight `a` in [0, amax]: yellow to dark red (the legend's gradient). */
export function edgeColour(a, amax) {
  const t = Math.max(0, Math.min(1, amax > 0 ? a / amax : 0));
  const stops = [[253, 174, 97], [240, 59, 32], [128, 0, 38]];
  const s = t * (stops.length - 1);
  const i = Math.min(stops.length - 2, Math.floor(s));
  const f = s - i;
  const c = stops[i].map((v, j) => Math.round(v + f * (stops[i + 1][j] - v)));
  return `rgb(${c[0]},${c[1]},${c[2]})`;
}

/** The view that shows every agent, goal and trail point with a margin. */
export function fitView(frame, trails, width, height) {
  let xmin = Infinity, xmax = -Infinity, ymin = Infinity, ymax = -Infinity;
  const take = (x, y) => {
    if (!Number.isFinite(x) || !Number.isFinite(y)) return;
    xmin = Math.min(xmin, x); xmax = Math.max(xmax, x);
    ymin = Math.min(ymin, y); ymax = Math.max(ymax, y);
  };
  for (const a of frame.agents) {
    take(a.x, a.y);
    if (a.kind === "vehicle" && a.goal) take(a.goal[0], a.goal[1]);
  }
  for (const pts of trails.values()) for (const [x, y] of pts) take(x, y);
  if (!Number.isFinite(xmin)) return { cx: 0, cy: 0, scale: 10 };
  const margin = 4;
  const w = Math.max(10, xmax - xmin + 2 * margin), h = Math.max(10, ymax - ymin + 2 * margin);
  return { cx: (xmin + xmax) / 2, cy: (ymin + ymax) / 2, scale: Math.min(width / w, height / h) };
}

export function toScreen(view, width, height, x, y) {
  return [width / 2 + (x - view.cx) * view.scale, height / 2 - (y - view.cy) * view.scale];
}

export function toWorld(view, width, height, px, py) {
  return [view.cx + (px - width / 2) / view.scale, view.cy - (py - height / 2) / view.scale];
}

/** A "nice" scale-bar length in metres: about 120 px long. */
function scaleBarMetres(scale) {
  const target = 120 / scale;
  const p = Math.pow(10, Math.floor(Math.log10(target)));
  for (const m of [5, 2, 1]) if (m * p <= target) return m * p;
  return p;
}

/**
 * Draws `frame` (readStates) with `edges` (already the strongest per agent), `trails`
 * (id -> [[x, y], ...]) and the `selected` agent id; returns the number of edges drawn.
 */
export function drawFrame(ctx, width, height, view, frame, edges, amax, trails, selected) {
  const S = (x, y) => toScreen(view, width, height, x, y);
  ctx.clearRect(0, 0, width, height);
  ctx.fillStyle = "#fff";
  ctx.fillRect(0, 0, width, height);
  const byId = new Map(frame.agents.map((a) => [a.id, a]));

  // Risk edges first, under the agents.
  let drawn = 0;
  for (const e of edges) {
    const p = byId.get(e.src), q = byId.get(e.dst);
    if (!p || !q) continue;
    const [x0, y0] = S(p.x, p.y), [x1, y1] = S(q.x, q.y);
    const emph = selected == null || e.src === selected || e.dst === selected;
    ctx.globalAlpha = emph ? 0.85 : 0.15;
    ctx.strokeStyle = edgeColour(e.a, amax);
    ctx.lineWidth = 0.5 + 4 * Math.min(1, amax > 0 ? e.a / amax : 0);
    ctx.beginPath(); ctx.moveTo(x0, y0); ctx.lineTo(x1, y1); ctx.stroke();
    drawn++;
  }
  ctx.globalAlpha = 1;

  // Trails.
  for (const [id, pts] of trails) {
    const a = byId.get(id);
    if (!a || a.kind !== "vehicle" || pts.length < 2) continue;
    ctx.strokeStyle = a.external ? "rgba(31,119,180,.6)" : "rgba(90,90,90,.5)";
    ctx.lineWidth = 1.5;
    ctx.setLineDash([4, 3]);
    ctx.beginPath();
    pts.forEach(([x, y], i) => { const [u, v] = S(x, y); if (i) ctx.lineTo(u, v); else ctx.moveTo(u, v); });
    ctx.stroke();
    ctx.setLineDash([]);
  }

  for (const a of frame.agents) {
    const [x, y] = S(a.x, a.y);
    if (a.kind === "vehicle") {
      if (a.goal) {
        const [gx, gy] = S(a.goal[0], a.goal[1]);
        ctx.strokeStyle = a.external ? "#1f77b4" : "#777";
        ctx.lineWidth = 2;
        ctx.beginPath();
        ctx.moveTo(gx - 6, gy - 6); ctx.lineTo(gx + 6, gy + 6);
        ctx.moveTo(gx - 6, gy + 6); ctx.lineTo(gx + 6, gy - 6);
        ctx.stroke();
      }
      ctx.save();
      ctx.translate(x, y);
      ctx.rotate(-a.heading);
      const l = a.length * view.scale, w = a.width * view.scale;
      // The learner's car blue, reactive cars amber (StatesMsg `reactive`, docs/MODEL.md
      // "Traffic"), replayed cars grey.
      ctx.fillStyle = a.external ? "#1f77b4" : a.reactive ? "#e0a030" : "#9a9a9a";
      ctx.strokeStyle = a.id === selected ? "#000" : "#333";
      ctx.lineWidth = a.id === selected ? 2.5 : 1;
      ctx.fillRect(-l / 2, -w / 2, l, w);
      ctx.strokeRect(-l / 2, -w / 2, l, w);
      ctx.fillStyle = "#fff"; // windscreen: which end is the front
      ctx.fillRect(l / 2 - Math.min(l * 0.25, 0.8 * view.scale), -w / 2 + 1, 2, w - 2);
      ctx.restore();
    } else {
      // A pedestrian a learner drives is purple with a ring and its goal marked; the
      // simulated and replayed ones green.
      const r = Math.max(2.5, (a.length / 2) * view.scale);
      const [fill, line] = a.external ? ["#9467bd", "#4b2a75"] : ["#2ca02c", "#1b5e1b"];
      if (a.external && a.goal) {
        const [gx, gy] = S(a.goal[0], a.goal[1]);
        ctx.strokeStyle = fill; ctx.lineWidth = 2;
        ctx.beginPath();
        ctx.moveTo(gx - 5, gy - 5); ctx.lineTo(gx + 5, gy + 5);
        ctx.moveTo(gx - 5, gy + 5); ctx.lineTo(gx + 5, gy - 5);
        ctx.stroke();
      }
      ctx.fillStyle = fill;
      ctx.strokeStyle = a.id === selected ? "#000" : line;
      ctx.lineWidth = a.id === selected ? 2.5 : 1;
      ctx.beginPath(); ctx.arc(x, y, r, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
      if (a.external) {
        ctx.strokeStyle = line; ctx.lineWidth = 1.5;
        ctx.beginPath(); ctx.arc(x, y, r + 3, 0, 2 * Math.PI); ctx.stroke();
      }
      const [vx, vy] = S(a.x + a.vx, a.y + a.vy);
      ctx.strokeStyle = line; ctx.lineWidth = 1.2;
      ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(vx, vy); ctx.stroke();
    }
  }

  // Scale bar and time.
  const m = scaleBarMetres(view.scale);
  const px = m * view.scale;
  ctx.strokeStyle = "#000"; ctx.lineWidth = 2;
  ctx.beginPath(); ctx.moveTo(16, height - 18); ctx.lineTo(16 + px, height - 18); ctx.stroke();
  ctx.fillStyle = "#000"; ctx.font = "12px system-ui";
  ctx.fillText(`${m} m`, 16, height - 24);
  ctx.fillText(`t = ${frame.t.toFixed(1)} s   step ${frame.step}   episode ${frame.episode}`, 16, 20);
  return drawn;
}
