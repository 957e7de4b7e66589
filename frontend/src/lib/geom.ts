/** Plane geometry in the site CRS (metres): polygons, bounding boxes, GeoJSON import. */

export type Pt = [number, number];
export type Ring = Pt[];

export interface BBox {
  minX: number;
  minY: number;
  maxX: number;
  maxY: number;
}

/** Signed area (shoelace; positive counter-clockwise). The ring may or may not repeat its first point. */
export function signedArea(ring: Ring): number {
  let a = 0;
  const n = ring.length;
  for (let i = 0; i < n; i++) {
    const [x1, y1] = ring[i];
    const [x2, y2] = ring[(i + 1) % n];
    a += x1 * y2 - x2 * y1;
  }
  return a / 2;
}

export function area(ring: Ring): number {
  return Math.abs(signedArea(ring));
}

export function perimeter(ring: Ring): number {
  let p = 0;
  for (let i = 0; i < ring.length; i++) {
    const a = ring[i], b = ring[(i + 1) % ring.length];
    p += Math.hypot(b[0] - a[0], b[1] - a[1]);
  }
  return p;
}

/** Even-odd rule point in polygon. */
export function pointInRing(x: number, y: number, ring: Ring): boolean {
  let inside = false;
  for (let i = 0, j = ring.length - 1; i < ring.length; j = i++) {
    const [xi, yi] = ring[i];
    const [xj, yj] = ring[j];
    if (yi > y !== yj > y && x < ((xj - xi) * (y - yi)) / (yj - yi) + xi) inside = !inside;
  }
  return inside;
}

export function bboxOf(points: Iterable<Pt>): BBox | null {
  let b: BBox | null = null;
  for (const [x, y] of points) {
    if (!b) b = { minX: x, minY: y, maxX: x, maxY: y };
    else {
      b.minX = Math.min(b.minX, x); b.minY = Math.min(b.minY, y);
      b.maxX = Math.max(b.maxX, x); b.maxY = Math.max(b.maxY, y);
    }
  }
  return b;
}

/** Ring without the closing duplicate point. */
export function openRing(ring: Ring): Ring {
  if (ring.length > 1) {
    const a = ring[0], b = ring[ring.length - 1];
    if (a[0] === b[0] && a[1] === b[1]) return ring.slice(0, -1);
  }
  return ring;
}

/** Does the ring cross itself? (O(n²), fine for hand-drawn outlines.) */
export function selfIntersects(ring: Ring): boolean {
  const r = openRing(ring);
  const n = r.length;
  const cross = (a: Pt, b: Pt, c: Pt) => (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
  for (let i = 0; i < n; i++) {
    const a = r[i], b = r[(i + 1) % n];
    for (let j = i + 1; j < n; j++) {
      if (j === i || (j + 1) % n === i || j === (i + 1) % n) continue;
      const c = r[j], d = r[(j + 1) % n];
      const d1 = cross(a, b, c), d2 = cross(a, b, d), d3 = cross(c, d, a), d4 = cross(c, d, b);
      if (((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0))) return true;
    }
  }
  return false;
}

export interface ImportedOutline {
  name: string;
  ring: Ring;
}

/**
 * Outlines from a GeoJSON text: a Polygon, a MultiPolygon (each part), a Feature or a FeatureCollection
 * of those; exterior rings only, coordinates taken as site-CRS metres (x = easting, y = northing).
 */
export function outlinesFromGeoJson(text: string): ImportedOutline[] {
  let doc: unknown;
  try {
    doc = JSON.parse(text);
  } catch (e) {
    throw new Error(`not JSON: ${(e as Error).message}`);
  }
  const out: ImportedOutline[] = [];
  const visit = (g: any, name: string) => {
    if (!g || typeof g !== "object") return;
    if (g.type === "FeatureCollection") (g.features ?? []).forEach((f: any, i: number) => visit(f, featureName(f, i)));
    else if (g.type === "Feature") visit(g.geometry, name);
    else if (g.type === "Polygon") out.push({ name, ring: toRing(g.coordinates?.[0]) });
    else if (g.type === "MultiPolygon") (g.coordinates ?? []).forEach((p: any, i: number) => out.push({ name: `${name} ${i + 1}`, ring: toRing(p?.[0]) }));
    else if (g.type === "GeometryCollection") (g.geometries ?? []).forEach((x: any) => visit(x, name));
  };
  visit(doc, "outline");
  const good = out.filter((o) => o.ring.length >= 3);
  if (!good.length) throw new Error("no polygon in the GeoJSON (expected Polygon, MultiPolygon or features of them)");
  const geographic = good.every((o) => o.ring.every(([x, y]) => Math.abs(x) <= 180 && Math.abs(y) <= 90));
  if (geographic) throw new Error("the coordinates look like longitude/latitude: export the outline in the site's projected CRS (metres)");
  return good;
}

function featureName(f: any, i: number): string {
  const p = f?.properties ?? {};
  return String(p.name ?? p.Name ?? p.id ?? p.label ?? `outline ${i + 1}`);
}

function toRing(coords: unknown): Ring {
  if (!Array.isArray(coords)) return [];
  const r: Ring = [];
  for (const c of coords) if (Array.isArray(c) && Number.isFinite(c[0]) && Number.isFinite(c[1])) r.push([Number(c[0]), Number(c[1])]);
  return openRing(r);
}

/** GeoJSON Polygon (closed ring, counter-clockwise exterior as RFC 7946 recommends). */
export function ringToGeoJson(ring: Ring): { type: "Polygon"; coordinates: number[][][] } {
  const r = openRing(ring);
  const ccw = signedArea(r) >= 0 ? r : [...r].reverse();
  return { type: "Polygon", coordinates: [[...ccw, ccw[0]].map(([x, y]) => [x, y])] };
}
