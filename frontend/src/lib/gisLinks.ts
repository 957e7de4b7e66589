/**
 * "Open in QGIS / GIS": the run's tile layers (GET /runs/{id}/tiles) and the URLs a GIS client reads with a
 * read-only tile token (POST /tokens/tile) in the query: the WMTS capabilities document and each layer's
 * XYZ template (docs/deliverables.md, "Tiles for GIS").
 */

import { API_BASE } from "../api/client";

export interface TileLayer {
  name: string;
  title: string;
  style: string;
  step: string;
  source: string;
  lonlat_bounds: number[];
  min_zoom: number;
  max_zoom: number;
  /** absolute URL template with {z}/{x}/{y} (the server's own origin) */
  tiles: string;
  legend: string;
}

export interface TileLayers {
  run_id: string;
  layers: TileLayer[];
}

export interface TileToken {
  id: string;
  name: string;
  prefix: string;
  scopes: string[];
  created_at: string;
  expires_at: string | null;
  /** the secret: shown once */
  token: string;
}

/** Days a tile token may live (backend accounts.TILE_TOKEN_MAX_DAYS). */
export const TILE_TOKEN_MAX_DAYS = 90;

function withToken(url: string, token: string): string {
  return `${url}${url.includes("?") ? "&" : "?"}token=${encodeURIComponent(token)}`;
}

/** The WMTS capabilities URL of a run with the token: QGIS "Add WMS/WMTS Layer", ArcGIS, GDAL's WMTS: driver. */
export function wmtsCapabilitiesUrl(origin: string, runId: string, token: string): string {
  return withToken(`${origin.replace(/\/+$/, "")}${API_BASE}/runs/${encodeURIComponent(runId)}/wmts/1.0.0/WMTSCapabilities.xml`, token);
}

/**
 * A layer's XYZ template with the token ({z}/{x}/{y} kept as is): QGIS "XYZ Tiles". The server writes the
 * template with the origin it was asked on; the path is put on the origin this page was loaded from (what
 * the user's machine reaches, also behind a proxy).
 */
export function xyzUrl(origin: string, layer: Pick<TileLayer, "tiles">, token: string): string {
  const i = layer.tiles.indexOf(`${API_BASE}/`);
  const url = i >= 0 ? `${origin.replace(/\/+$/, "")}${layer.tiles.slice(i)}` : layer.tiles;
  return withToken(url, token);
}

/** The number of days typed for a new tile token, kept within 1 to 90 (whole days). */
export function clampTokenDays(days: number): number {
  if (!Number.isFinite(days)) return 30;
  return Math.min(TILE_TOKEN_MAX_DAYS, Math.max(1, Math.round(days)));
}

/** "expires 2024-07-30 14:02 UTC (in 30 days)"; "expires in 5 hours"; "has expired"; "does not expire". */
export function expiryText(expiresAt: string | null | undefined, now: Date = new Date()): string {
  if (!expiresAt) return "does not expire";
  const t = Date.parse(expiresAt);
  if (!Number.isFinite(t)) return `expires ${expiresAt}`;
  const ms = t - now.getTime();
  if (ms <= 0) return "has expired";
  const iso = new Date(t).toISOString();
  const when = `${iso.slice(0, 10)} ${iso.slice(11, 16)} UTC`;
  const hours = ms / 3600e3;
  const rel = hours < 48 ? `${Math.max(1, Math.round(hours))} hour${Math.round(hours) === 1 ? "" : "s"}` : `${Math.round(hours / 24)} days`;
  return `expires ${when} (in ${rel})`;
}
