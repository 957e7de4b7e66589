/**
 * The rough edges a new user met on a fresh clone (issue 24): the flight date, volumes written one way,
 * the PPK chart's epoch count and axis labels, the run log read page by page, the map that follows its
 * extent until the user moves it.
 */

import { readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { afterEach, describe, expect, it, vi } from "vitest";
import { getAllPages } from "../src/api/client";
import { followView } from "../src/components/MapView";
import { PpkChart } from "../src/components/PpkChart";
import { flightDate, formatVolume, formatVolumeNumber, formatVolumePm } from "../src/lib/format";
import { qualityFromSummary } from "../src/lib/ppkQuality";
import { spacedTicks, tickLabel } from "../src/lib/scale";

const here = dirname(fileURLToPath(import.meta.url));

/** Every element of a rendered vnode tree (function components are not expanded: PpkChart draws SVG itself). */
function elements(node: any, out: any[] = []): any[] {
  if (Array.isArray(node)) {
    for (const n of node) elements(n, out);
  } else if (node && typeof node === "object" && "props" in node) {
    out.push(node);
    elements(node.props?.children, out);
  }
  return out;
}

function text(node: any): string {
  if (node === null || node === undefined || typeof node === "boolean") return "";
  if (typeof node === "string" || typeof node === "number") return String(node);
  if (Array.isArray(node)) return node.map(text).join("");
  return text(node.props?.children);
}

describe("volumes are written by one rule (the PDF report's: backend/services/display.py)", () => {
  const cases = JSON.parse(readFileSync(join(here, "fixtures", "volume_format_cases.json"), "utf8")).cases as
    { m3: number | null; sigma_m3: number | null; number: string; with_sigma: string }[];
  it.each(cases)("$m3 ± $sigma_m3 -> $with_sigma", (c) => {
    const dash = (s: string) => (s === "-" ? "–" : s);
    expect(formatVolumeNumber(c.m3, c.sigma_m3)).toBe(dash(c.number));
    expect(formatVolumePm(c.m3, c.sigma_m3)).toBe(c.m3 === null ? "–" : `${c.with_sigma} m³`);
  });
  it("gives piles of one run the same precision (not 15.3 / 9.32 / 16.5)", () => {
    const shown = [[15.2412, 0.1312], [9.3201, 0.1], [16.5, 0.14]].map(([v, s]) => formatVolume(v, s));
    expect(shown).toEqual(["15.24 m³", "9.32 m³", "16.50 m³"]);
  });
});

describe("the flight date", () => {
  const base = { created_at: "2025-03-01T09:00:00Z" };
  it("is never the upload date: unknown until the data or the user gives it", () => {
    const d = flightDate({ ...base, flown_at: null, flown_at_source: null });
    expect(d.known).toBe(false);
    expect(d.text).not.toContain("2025-03-01");
  });
  it("says where a date read from the data comes from", () => {
    const d = flightDate({ ...base, flown_at: "2024-06-24T08:10:00Z", flown_at_source: "gnss" });
    expect(d.text).toBe("2024-06-24");
    expect(d.note).toContain("GNSS");
    expect(flightDate({ ...base, flown_at: "2024-06-24T08:10:00Z", flown_at_source: "user" }).note).toBe("");
  });
});

describe("PPK chart", () => {
  // 550 epochs at 2 Hz; the accuracy view fetches every 2nd (275), the GNSS step counted 550
  const all = Array.from({ length: 550 }, (_, i) => ({ gps_time_s: 1.4e9 + i * 0.5, q: i < 500 ? 1 : 2, ns: 14, ratio: i < 500 ? 40 : 1.5, sdu_m: 0.003 + (i % 7) * 0.0002 }));
  const every2 = all.filter((_, i) => i % 2 === 0);
  const summary = { epochs: 550, fix: 500, float: 50, single: 0, fix_rate: 500 / 550 };

  it("states the GNSS step's epoch count, not the length of the decimated trajectory", () => {
    const vnode = PpkChart({ epochs: every2, counts: qualityFromSummary(summary) });
    const caption = text(elements(vnode).find((e) => e.type === "figcaption"));
    expect(caption).toContain("550 epochs");
    expect(caption).toContain("91 % fix");
  });

  it("labels a millimetre sigma-up axis with distinct values, and the ratio axis without overlaps", () => {
    const vnode = PpkChart({ epochs: every2, counts: qualityFromSummary(summary) });
    const texts = elements(vnode).filter((e) => e.type === "text");
    const title = texts.find((t) => text(t).startsWith("σ up"));
    expect(text(title)).toBe("σ up (mm)");
    // the right-axis labels (x = W - R - 2), grouped by panel through their y
    const axis = texts.filter((t) => t.props["text-anchor"] === "end" && t.props.x > 600).map((t) => ({ y: t.props.y as number, s: text(t) }));
    const sigmaPanelY = title.props.y as number;
    const sigmaLabels = axis.filter((a) => Math.abs(a.y - sigmaPanelY) < 40).map((a) => a.s);
    expect(sigmaLabels.length).toBeGreaterThanOrEqual(2);
    expect(new Set(sigmaLabels).size).toBe(sigmaLabels.length);         // not "0 ... 0"
    expect(sigmaLabels.some((s) => Number(s) > 0)).toBe(true);
    const ys = axis.map((a) => a.y).sort((a, b) => a - b);
    for (let i = 1; i < ys.length; i++) expect(ys[i] - ys[i - 1]).toBeGreaterThanOrEqual(10);   // no label over another
  });

  it("keeps tick labels apart and writes them with the decimals they need", () => {
    const px = (v: number) => 100 - v * 2;
    expect(spacedTicks([0, 50, 3], px, 11)).toEqual([0, 50]);
    expect([0, 0.2, 0.4].map((t) => tickLabel(t, [0, 0.2, 0.4]))).toEqual(["0.0", "0.2", "0.4"]);
    expect([0, 2.5, 5].map((t) => tickLabel(t, [0, 2.5, 5]))).toEqual(["0.0", "2.5", "5.0"]);
    expect([0, 2, 4].map((t) => tickLabel(t, [0, 2, 4]))).toEqual(["0", "2", "4"]);
  });
});

describe("paginated lists", () => {
  afterEach(() => vi.unstubAllGlobals());
  it("reads every page of the run log ({items, total, limit, offset})", async () => {
    const lines = Array.from({ length: 1203 }, (_, i) => ({ id: i + 1, message: `line ${i + 1}` }));
    const asked: string[] = [];
    vi.stubGlobal("fetch", async (url: string) => {
      asked.push(url);
      const q = new URL(url, "http://x").searchParams;
      const limit = Number(q.get("limit")), offset = Number(q.get("offset"));
      const body = { items: lines.slice(offset, offset + limit), total: lines.length, limit, offset };
      return new Response(JSON.stringify(body), { status: 200, headers: { "Content-Type": "application/json" } });
    });
    const got = await getAllPages<{ id: number }>("/runs/r1/logs");
    expect(got.map((l) => l.id)).toEqual(lines.map((l) => l.id));
    expect(asked).toHaveLength(3);
    expect(asked[0]).toContain("/api/v1/runs/r1/logs?limit=500&offset=0");
  });
});

describe("the map's view", () => {
  const points = { minX: 100, minY: 100, maxX: 140, maxY: 130 };          // what is known first
  const ortho = { minX: 0, minY: 0, maxX: 400, maxY: 300 };               // the orthophoto, later
  it("follows a later, larger extent and a new size until the user moves it", () => {
    let v = followView(null, false, points, { w: 800, h: 520 });
    expect(v!.cx).toBe(120);
    v = followView(v, false, ortho, { w: 800, h: 520 });                  // not left cropped to the points
    expect(v).toMatchObject({ cx: 200, cy: 150 });
    const shown = (view: typeof v, w: number, h: number) => ({ minX: view!.cx - (w / 2) * view!.res, maxX: view!.cx + (w / 2) * view!.res, minY: view!.cy - (h / 2) * view!.res, maxY: view!.cy + (h / 2) * view!.res });
    let s = shown(v, 800, 520);
    expect(s.minX <= 0 && s.maxX >= 400 && s.minY <= 0 && s.maxY >= 300).toBe(true);
    v = followView(v, false, ortho, { w: 500, h: 520 });                  // the tab laid out narrower
    s = shown(v, 500, 520);
    expect(s.minX <= 0 && s.maxX >= 400).toBe(true);
    expect(followView(v, false, ortho, { w: 0, h: 0 })).toBe(v);          // hidden: kept until measured
    const mine = { cx: 10, cy: 10, res: 0.05 };
    expect(followView(mine, true, ortho, { w: 900, h: 520 })).toBe(mine); // the user's view is theirs
  });
});
