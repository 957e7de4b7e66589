/**
 * A basemap-free plan view in the site's projected CRS: raster layers (orthophoto, shaded DSM,
 * change map) on a canvas, vectors (ground points, stockpile outlines, the outline being drawn) in SVG.
 * Pan by dragging or with the arrow keys, zoom with the wheel or +/−; when drawing, click to add a
 * corner (or Space at the centre cross, for keyboard users), Enter or double-click to close.
 */

import type { ComponentChildren } from "preact";
import { useEffect, useLayoutEffect, useRef, useState } from "preact/hooks";
import type { BBox, Pt, Ring } from "../lib/geom";

export interface RasterLayer {
  id: string;
  canvas: HTMLCanvasElement;
  bbox: BBox;
  opacity?: number;
  smooth?: boolean;
}

export interface MapOutline {
  id: string;
  name: string;
  ring: Ring;
  kind?: "pile" | "selected" | "draft" | "design";
}

export interface MapPoint {
  name: string;
  x: number;
  y: number;
  role: string;
}

export interface Drawing {
  ring: Ring;
  onAdd: (p: Pt) => void;
  onClose: () => void;
  onUndo: () => void;
  onCancel: () => void;
}

export interface ViewState {
  cx: number;
  cy: number;
  /** metres per CSS pixel */
  res: number;
}

interface Props {
  label: string;
  extent: BBox | null;
  rasters: RasterLayer[];
  points?: MapPoint[];
  outlines?: MapOutline[];
  drawing?: Drawing | null;
  onView?: (bbox: BBox, pxPerM: number) => void;
  onSelectOutline?: (id: string) => void;
  readout?: (x: number, y: number) => string | null;
  legend?: ComponentChildren;
  /** Shown over the map's top-left corner (drawing hints and buttons): never moves the map. */
  overlay?: ComponentChildren;
  height?: number;
}

/** The view that shows all of `extent` in a `size` CSS-pixel map, with a 20 px margin. */
export function fitView(extent: BBox, size: { w: number; h: number }): ViewState {
  const res = Math.max((extent.maxX - extent.minX) / Math.max(1, size.w - 40), (extent.maxY - extent.minY) / Math.max(1, size.h - 40), 0.01);
  return { cx: (extent.minX + extent.maxX) / 2, cy: (extent.minY + extent.maxY) / 2, res };
}

/**
 * The view after the extent or the map's size changed: fitted to the extent until the user pans or zooms
 * (a map opened before its orthophoto arrived, or measured before its tab was laid out, is not left
 * showing a crop of it); once the user moved it, theirs.
 */
export function followView(view: ViewState | null, userMoved: boolean, extent: BBox | null, size: { w: number; h: number }): ViewState | null {
  if (userMoved && view) return view;
  if (!extent || !(size.w > 0) || !(size.h > 0)) return view;
  return fitView(extent, size);
}

export function MapView(p: Props) {
  const wrap = useRef<HTMLDivElement>(null);
  const canvas = useRef<HTMLCanvasElement>(null);
  const [size, setSize] = useState({ w: 800, h: p.height ?? 480 });
  const [view, setView] = useState<ViewState | null>(null);
  const [cursor, setCursor] = useState<Pt | null>(null);
  const drag = useRef<{ x: number; y: number; moved: boolean; view: ViewState } | null>(null);
  // the user panned or zoomed: the view is theirs (else it follows the extent and the map's size)
  const userMoved = useRef(false);

  // Track the element size.
  useLayoutEffect(() => {
    const el = wrap.current!;
    const ro = new ResizeObserver(() => setSize({ w: el.clientWidth, h: el.clientHeight }));
    ro.observe(el);
    setSize({ w: el.clientWidth, h: el.clientHeight });
    return () => ro.disconnect();
  }, []);

  const fit = () => {
    if (!p.extent) return;
    userMoved.current = false;
    setView(fitView(p.extent, size));
  };
  const extentKey = p.extent ? `${p.extent.minX},${p.extent.minY},${p.extent.maxX},${p.extent.maxY}` : "";
  useLayoutEffect(() => {
    const next = followView(view, userMoved.current, p.extent, size);
    if (next !== view) setView(next);
  }, [extentKey, size.w, size.h]);
  const move = (next: ViewState) => {
    userMoved.current = true;
    setView(next);
  };

  const v = view;
  const toScreen = (x: number, y: number): [number, number] => (v ? [(x - v.cx) / v.res + size.w / 2, size.h / 2 - (y - v.cy) / v.res] : [0, 0]);
  const toWorld = (sx: number, sy: number): Pt => (v ? [v.cx + (sx - size.w / 2) * v.res, v.cy - (sy - size.h / 2) * v.res] : [0, 0]);

  // Draw rasters.
  useEffect(() => {
    const c = canvas.current;
    if (!c || !v) return;
    const dpr = window.devicePixelRatio || 1;
    c.width = Math.round(size.w * dpr);
    c.height = Math.round(size.h * dpr);
    const g = c.getContext("2d")!;
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, size.w, size.h);
    for (const r of p.rasters) {
      const [x0, y0] = toScreen(r.bbox.minX, r.bbox.maxY);
      const [x1, y1] = toScreen(r.bbox.maxX, r.bbox.minY);
      g.globalAlpha = r.opacity ?? 1;
      g.imageSmoothingEnabled = r.smooth ?? (x1 - x0) < r.canvas.width * 2;
      g.drawImage(r.canvas, x0, y0, x1 - x0, y1 - y0);
    }
    g.globalAlpha = 1;
  }, [p.rasters, v, size.w, size.h]);

  // Tell the parent what is shown (for loading finer raster windows), once the view settles.
  useEffect(() => {
    if (!v || !p.onView) return;
    const t = setTimeout(() => {
      const [a, b] = [toWorld(0, size.h), toWorld(size.w, 0)];
      p.onView!({ minX: a[0], minY: a[1], maxX: b[0], maxY: b[1] }, (window.devicePixelRatio || 1) / v.res);
    }, 250);
    return () => clearTimeout(t);
  }, [v?.cx, v?.cy, v?.res, size.w, size.h]);

  const zoom = (f: number, sx = size.w / 2, sy = size.h / 2) => {
    if (!v) return;
    const [wx, wy] = toWorld(sx, sy);
    const res = Math.min(1000, Math.max(0.002, v.res * f));
    move({ res, cx: wx - (sx - size.w / 2) * res, cy: wy + (sy - size.h / 2) * res });
  };

  const local = (e: MouseEvent): [number, number] => {
    const r = wrap.current!.getBoundingClientRect();
    return [e.clientX - r.left, e.clientY - r.top];
  };

  const onPointerDown = (e: PointerEvent) => {
    if (!v || e.button !== 0) return;
    (e.currentTarget as Element).setPointerCapture?.(e.pointerId);
    const [x, y] = local(e);
    drag.current = { x, y, moved: false, view: v };
  };
  const onPointerMove = (e: PointerEvent) => {
    const [x, y] = local(e);
    if (v) setCursor(toWorld(x, y));
    const d = drag.current;
    if (!d) return;
    if (Math.hypot(x - d.x, y - d.y) > 4) d.moved = true;
    if (d.moved) move({ ...d.view, cx: d.view.cx - (x - d.x) * d.view.res, cy: d.view.cy + (y - d.y) * d.view.res });
  };
  const onPointerUp = (e: PointerEvent) => {
    const d = drag.current;
    drag.current = null;
    if (d && !d.moved && p.drawing) {
      const [x, y] = local(e);
      p.drawing.onAdd(toWorld(x, y));
    }
  };
  const onWheel = (e: WheelEvent) => {
    e.preventDefault();
    const [x, y] = local(e);
    zoom(Math.exp(e.deltaY * 0.0015), x, y);
  };
  const onKey = (e: KeyboardEvent) => {
    if (!v) return;
    const step = 60 * v.res;
    const k = e.key;
    let used = true;
    if (k === "ArrowLeft") move({ ...v, cx: v.cx - step });
    else if (k === "ArrowRight") move({ ...v, cx: v.cx + step });
    else if (k === "ArrowUp") move({ ...v, cy: v.cy + step });
    else if (k === "ArrowDown") move({ ...v, cy: v.cy - step });
    else if (k === "+" || k === "=") zoom(1 / 1.5);
    else if (k === "-" || k === "_") zoom(1.5);
    else if (k === "0") fit();
    else if (p.drawing && (k === " " || k === "Spacebar")) p.drawing.onAdd([v.cx, v.cy]);
    else if (p.drawing && k === "Enter") p.drawing.onClose();
    else if (p.drawing && k === "Backspace") p.drawing.onUndo();
    else if (p.drawing && k === "Escape") p.drawing.onCancel();
    else used = false;
    if (used) e.preventDefault();
  };

  const pts = (ring: Ring) => ring.map(([x, y]) => toScreen(x, y).map((q) => q.toFixed(1)).join(",")).join(" ");
  const scaleM = v ? niceLen(v.res * 120) : 0;
  const readout = cursor ? p.readout?.(cursor[0], cursor[1]) : null;

  return (
    <div class="map-block">
      <div class="map-toolbar" role="toolbar" aria-label="Map controls">
        <button type="button" class="icon" onClick={() => zoom(1 / 1.5)} aria-label="Zoom in">+</button>
        <button type="button" class="icon" onClick={() => zoom(1.5)} aria-label="Zoom out">−</button>
        <button type="button" class="secondary small" onClick={fit}>Fit</button>
        <span class="small muted map-readout" aria-live="off">
          {cursor ? `E ${cursor[0].toFixed(2)}  N ${cursor[1].toFixed(2)}${readout ? `  ${readout}` : ""}` : "E, N of the cursor"}
        </span>
      </div>
      <div
        ref={wrap}
        class={p.drawing ? "map drawing" : "map"}
        style={{ height: `${p.height ?? 480}px` }}
        tabIndex={0}
        role="application"
        aria-label={`${p.label}. Arrow keys pan, plus and minus zoom, 0 fits${p.drawing ? "; Space adds a corner at the centre cross, Enter closes the outline, Backspace removes the last corner, Escape cancels" : ""}.`}
        onPointerDown={onPointerDown}
        onPointerMove={onPointerMove}
        onPointerUp={onPointerUp}
        onPointerLeave={() => setCursor(null)}
        onDblClick={(e) => { if (p.drawing) { e.preventDefault(); p.drawing.onClose(); } }}
        onWheel={onWheel}
        onKeyDown={onKey}
        data-testid="map"
        data-view={v ? `${v.cx},${v.cy},${v.res}` : undefined}
        data-rasters={p.rasters.map((r) => r.id).join(" ")}
      >
        <canvas ref={canvas} style={{ width: `${size.w}px`, height: `${size.h}px` }} aria-hidden="true" />
        {v ? (
          <svg class="map-overlay" width={size.w} height={size.h} aria-hidden="true">
            {(p.outlines ?? []).map((o) => {
              const c = o.ring.length ? centroidScreen(o.ring, toScreen) : null;
              return (
                <g key={o.id} class={`outline outline-${o.kind ?? "pile"}`} onClick={() => p.onSelectOutline?.(o.id)}>
                  <polygon points={pts(o.ring)} />
                  {c ? <text x={c[0]} y={c[1]} text-anchor="middle" class="outline-label">{o.name}</text> : null}
                </g>
              );
            })}
            {(p.points ?? []).map((q) => {
              const [x, y] = toScreen(q.x, q.y);
              return (
                <g key={q.name} class={`gpoint gpoint-${q.role}`}>
                  {q.role === "control" ? <path d={`M${x},${y - 7} l6,11 h-12 z`} /> : <circle cx={x} cy={y} r={5} />}
                  <text x={x + 8} y={y - 6}>{q.name}</text>
                </g>
              );
            })}
            {p.drawing ? (
              <g class="draft">
                {p.drawing.ring.length > 1 ? <polyline points={pts(p.drawing.ring)} /> : null}
                {p.drawing.ring.length > 2 ? <line class="closing" x1={toScreen(...p.drawing.ring[p.drawing.ring.length - 1])[0]} y1={toScreen(...p.drawing.ring[p.drawing.ring.length - 1])[1]} x2={toScreen(...p.drawing.ring[0])[0]} y2={toScreen(...p.drawing.ring[0])[1]} /> : null}
                {p.drawing.ring.map(([x, y], i) => {
                  const [sx, sy] = toScreen(x, y);
                  return <circle key={i} cx={sx} cy={sy} r={4} />;
                })}
                <path class="crosshair" d={`M${size.w / 2 - 10},${size.h / 2} h20 M${size.w / 2},${size.h / 2 - 10} v20`} />
              </g>
            ) : null}
            <g class="scalebar-g" transform={`translate(16, ${size.h - 18})`}>
              <rect x={-6} y={-18} width={scaleM / v.res + 12} height={26} class="scale-bg" />
              <line x1={0} y1={0} x2={scaleM / v.res} y2={0} class="scalebar" />
              <text x={0} y={-6} class="scale-text">{scaleM >= 1 ? `${scaleM} m` : `${Math.round(scaleM * 100)} cm`}</text>
            </g>
            <g transform={`translate(${size.w - 22}, 26)`} class="north-g">
              <path d="M0,-14 l6,14 h-12 z" />
              <text y={12} text-anchor="middle">N</text>
            </g>
          </svg>
        ) : null}
        {!p.extent ? <div class="map-empty">Nothing to show yet.</div> : null}
        {p.overlay ? <div class="map-overlay-box" onPointerDown={(e) => e.stopPropagation()} onPointerUp={(e) => e.stopPropagation()} onDblClick={(e) => e.stopPropagation()}>{p.overlay}</div> : null}
      </div>
      {p.legend ? <div class="map-legend">{p.legend}</div> : null}
    </div>
  );
}

function niceLen(m: number): number {
  const mag = 10 ** Math.floor(Math.log10(m));
  const f = m / mag;
  return (f < 2 ? 1 : f < 5 ? 2 : 5) * mag;
}

function centroidScreen(ring: Ring, toScreen: (x: number, y: number) => [number, number]): [number, number] {
  let x = 0, y = 0;
  for (const [a, b] of ring) {
    x += a;
    y += b;
  }
  return toScreen(x / ring.length, y / ring.length);
}
