/**
 * The site calibration table of the run view (components/CalibrationTable, lib/calibration) on the datum step's
 * real summary: fixtures/datum_calibration.json is what georef_core/steps/datum.py writes for a simulated site
 * whose point K5 (the centre) carries a 5 cm height blunder (tests/datums/test_calibration_step.py checks it is current).
 */

import { readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { describe, expect, it } from "vitest";
import { CalibrationTable } from "../src/components/CalibrationTable";
import { calibrationOf, calibrationParameterLines, formatResidualMm } from "../src/lib/calibration";
import { classify, uploadKindOf } from "../src/lib/sniff";

const here = dirname(fileURLToPath(import.meta.url));
const summary = JSON.parse(readFileSync(join(here, "fixtures", "datum_calibration.json"), "utf8"));

function text(node: any): string {
  if (node === null || node === undefined || typeof node === "boolean") return "";
  if (typeof node === "string" || typeof node === "number") return String(node);
  if (Array.isArray(node)) return node.map(text).join("");
  return text(node.props?.children);
}

function find(node: any, type: string, out: any[] = []): any[] {
  if (Array.isArray(node)) for (const n of node) find(n, type, out);
  else if (node && typeof node === "object" && "props" in node) {
    if (node.type === type) out.push(node);
    find(node.props?.children, type, out);
  }
  return out;
}

describe("site calibration in the run view", () => {
  const cal = calibrationOf({ datum: "ellipsoidal height (WGS84)", calibration: summary })!;

  it("reads the datum step's summary, and nothing from a step without a calibration", () => {
    expect(cal.residuals.map((r) => r.name)).toEqual(["K1", "K2", "K3", "K4", "K5"]);
    expect(calibrationOf({ skipped: true, reason: "ellipsoidal" })).toBeNull();
    expect(calibrationOf(null)).toBeNull();
  });

  it("shows one row per point: dE / dN / dH in mm, signed, the blunder where it is", () => {
    const vnode = CalibrationTable({ c: cal });
    const rows = find(vnode, "tbody")[0].props.children as any[];
    expect(rows.length).toBe(5);
    const cells = rows.map((r) => find(r, "td").map(text));
    const kb = rows.findIndex((r) => text(find(r, "th")[0]) === "K5");
    const dh = summary.residuals.map((r: any) => Math.abs(r.dH_m));
    expect(kb).toBe(dh.indexOf(Math.max(...dh)));
    for (let i = 0; i < rows.length; i++) {
      const r = summary.residuals[i];
      expect(cells[i]).toEqual([r.use, formatResidualMm(r.dE_m), formatResidualMm(r.dN_m), formatResidualMm(r.dH_m)]);
    }
    expect(Math.abs(Number(cells[kb][3].replace("−", "-")))).toBeGreaterThan(10);
    expect(formatResidualMm(null)).toBe("–");
    expect(formatResidualMm(-0.00042)).toBe("−0.4");
  });

  it("states the parameters: scale in ppm, rotation, the vertical plane and the residuals' RMS", () => {
    const lines = calibrationParameterLines(cal);
    expect(lines[0]).toMatch(/^scale 1\.0000\d+ \(\+2\d\.\d ppm/);
    expect(lines[0]).toContain(`rotation +${summary.horizontal.rotation_deg.toFixed(6)}°`);
    expect(Math.abs(summary.horizontal.rotation_deg - 0.35)).toBeLessThan(1e-3);
    expect(lines.some((l) => l.startsWith("vertical (inclined plane): shift −47.2"))).toBe(true);
    expect(lines[lines.length - 1]).toContain(`vertical ${(summary.statistics.rms_vertical_m * 1000).toFixed(1)} mm`);
    expect(text(CalibrationTable({ c: cal }))).toContain("calibration/pairs.csv");
  });
});

describe("a site calibration dropped into the upload", () => {
  const enc = new TextEncoder();
  it("is a site calibration, not survey.json nor the ground points", () => {
    const j = enc.encode(JSON.stringify({ format: "georef-site-calibration", version: 1, name: "North grid", points: [{}, {}, {}, {}] }));
    const s = classify("cal.json", j, j, "none");
    expect(s.kind).toBe("site-calibration");
    expect(s.description).toBe("site calibration “North grid” (4 control points)");
    expect(uploadKindOf(s, null)).toBe("site-calibration");
    const csv = enc.encode("name,easting_m,northing_m,height_m,local_e_m,local_n_m,local_h_m\nK1,1,2,3,4,5,6\nK2,1,2,3,4,5,6\nK3,1,2,3,4,5,6\n");
    const c = classify("pairs.csv", csv, csv, "none");
    expect(c.kind).toBe("site-calibration");
    expect(c.description).toBe("site calibration control pairs (3 points)");
    // a points table without the local grid's columns stays ground points
    const pts = enc.encode("name,easting_m,northing_m,height_m,role\nG1,1,2,3,control\n");
    expect(classify("points.csv", pts, pts, "none").kind).toBe("points");
  });
});
