/**
 * The stockpile inventory of a site at a date (GET /sites/{id}/inventory, computed by
 * georef_core.deliverables.inventory): its JSON shape, the download links, and how its figures are written
 * ("15.24" with "± 0.13 (1σ)"; the 95 % half-width in the cell's title).
 */

import { apiUrl } from "../api/client";
import { volumeDecimals } from "./format";

/** One row of the inventory (the core's COLUMNS; units in the names). */
export interface InventoryRow {
  stockpile: string;
  material: string | null;
  survey: string | null;
  survey_date: string | null;
  volume_m3: number | null;
  volume_sigma_m3: number | null;
  volume_ci95_m3: number | null;
  density_t_m3: number | null;
  density_sigma_t_m3: number | null;
  density_source: string | null;
  tonnes_t: number | null;
  tonnes_sigma_t: number | null;
  tonnes_ci95_t: number | null;
  previous_survey_date: string | null;
  change_m3: number | null;
  change_sigma_m3: number | null;
  change_ci95_m3: number | null;
  status: string | null;
}

export interface InventoryDoc {
  site_id: string;
  site: string;
  date: string;
  units: Record<string, string>;
  uncertainty: string;
  columns: string[];
  stockpiles: InventoryRow[];
  totals: InventoryRow;
  notes: string[];
}

export type InventoryFormat = "json" | "csv" | "xlsx";

/** Today's date in UTC ("2024-06-30"): the server's default date too. */
export function todayUtc(now: Date = new Date()): string {
  return now.toISOString().slice(0, 10);
}

/** True for a real calendar date written YYYY-MM-DD (what the server accepts). */
export function isIsoDate(s: string): boolean {
  if (!/^\d{4}-\d{2}-\d{2}$/.test(s)) return false;
  const d = new Date(`${s}T00:00:00Z`);
  return !Number.isNaN(d.getTime()) && d.toISOString().slice(0, 10) === s;
}

/** The inventory's URL (a download link for csv/xlsx: the session cookie authorises a plain GET). */
export function inventoryUrl(siteId: string, date: string, format: InventoryFormat): string {
  return apiUrl(`/sites/${encodeURIComponent(siteId)}/inventory`, { date: isIsoDate(date) ? date : null, format });
}

/** A value with its uncertainty, as table cell parts. */
export interface PmText {
  /** "15.24" ("+3.20" when signed), "–" without a value */
  value: string;
  /** "± 0.13 (1σ)", or "" when no uncertainty is known */
  pm: string;
  /** "95 %: ± 0.25" for a title, or "" */
  ci95: string;
}

function fixed(v: number, decimals: number): string {
  const s = v.toLocaleString("en-GB", { minimumFractionDigits: decimals, maximumFractionDigits: decimals, useGrouping: true });
  return /^-0(\.0*)?$/.test(s) ? s.slice(1) : s; // no "-0.00"
}

/**
 * `value ± sigma (1σ)` with the volume rule's decimals (as many as the uncertainty supports: its first two
 * significant digits; without one, by magnitude), at most `maxDecimals` (2: the server rounds the inventory
 * to 0.01). `signed`: "+" before a positive value (a change).
 */
export function formatPm(
  value: number | null | undefined,
  sigma: number | null | undefined,
  opts: { maxDecimals?: number; signed?: boolean; ci95?: number | null } = {},
): PmText {
  if (value === null || value === undefined || !Number.isFinite(value)) return { value: "–", pm: "", ci95: "" };
  const hasSigma = typeof sigma === "number" && Number.isFinite(sigma) && sigma > 0;
  const dec = Math.min(opts.maxDecimals ?? 2, volumeDecimals(value, hasSigma ? sigma : null));
  let v = fixed(value, dec);
  if (opts.signed && Number(v.replace(/,/g, "")) > 0) v = `+${v}`;
  const pm = hasSigma ? `± ${fixed(sigma as number, dec)} (1σ)` : "";
  const ci = typeof opts.ci95 === "number" && Number.isFinite(opts.ci95) && opts.ci95 > 0 ? `95 %: ± ${fixed(opts.ci95, dec)}` : "";
  return { value: v, pm, ci95: ci };
}

/** The cells of one inventory row as shown (the totals row too). */
export interface InventoryCells {
  pile: string;
  material: string;
  surveyed: string;
  volume: PmText;
  density: PmText;
  densityNote: string;
  tonnes: PmText;
  change: PmText;
  changeNote: string;
  status: string;
  measured: boolean;
}

/** "crushed_stone" -> "Crushed stone" (the server's material_label rule; words typed by people kept). */
export function materialLabel(material: string | null | undefined, known?: Map<string, string>): string {
  const m = (material ?? "").trim();
  if (!m) return "";
  const k = known?.get(m);
  if (k) return k;
  if (/^[a-z0-9]+([_-][a-z0-9]+)*$/.test(m)) {
    const words = m.split(/[_-]/).join(" ");
    return words[0].toUpperCase() + words.slice(1);
  }
  return m;
}

export function inventoryCells(r: InventoryRow, labels?: Map<string, string>): InventoryCells {
  const measured = r.volume_m3 !== null && r.volume_m3 !== undefined;
  const dens = r.density_t_m3 ?? null;
  let densityNote = "";
  if (dens === null) densityNote = r.stockpile === "TOTAL" ? "" : "no density: volume only";
  else if (r.density_source) densityNote = r.density_source;
  return {
    pile: r.stockpile,
    material: materialLabel(r.material, labels),
    surveyed: r.survey_date ? `${r.survey_date}${r.survey ? ` · ${r.survey}` : ""}` : "",
    volume: formatPm(r.volume_m3, r.volume_sigma_m3, { ci95: r.volume_ci95_m3 }),
    // densities are given to 0.001 t/m³ by the server
    density: formatPm(dens, r.density_sigma_t_m3, { maxDecimals: 3 }),
    densityNote,
    tonnes: formatPm(r.tonnes_t, r.tonnes_sigma_t, { ci95: r.tonnes_ci95_t }),
    change: formatPm(r.change_m3, r.change_sigma_m3, { signed: true, ci95: r.change_ci95_m3 }),
    changeNote: r.previous_survey_date ? `since ${r.previous_survey_date}` : measured && r.stockpile !== "TOTAL" ? "first survey" : "",
    status: r.status ?? "",
    measured,
  };
}
