/**
 * The site page's calibration (views/SiteCalibrationPanel, lib/calibration.siteCalibrationBody): the file a user
 * picks becomes the body of PUT /sites/{id}/calibration by content: a calibration JSON document as such, a CSV of
 * control pairs to be solved by the server; anything else refused with the reason before it is sent.
 */

import { readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { describe, expect, it } from "vitest";
import { siteCalibrationBody } from "../src/lib/calibration";

const here = dirname(fileURLToPath(import.meta.url));
const summary = JSON.parse(readFileSync(join(here, "fixtures", "datum_calibration.json"), "utf8"));

const PAIRS = "name,easting_m,northing_m,height_m,local_e_m,local_n_m,local_h_m\nK1,448005,5412008,150.1,1005.2,2007.9,102.85\n";

describe("site calibration from a picked file", () => {
  it("sends a calibration document as the document, a pairs CSV as text to solve", () => {
    const doc = { format: "georef-site-calibration", version: 1, name: summary.name, crs: summary.crs };
    const b = siteCalibrationBody("office.json", "\uFEFF  " + JSON.stringify(doc));
    expect(b).toEqual({ document: doc, source_name: "office.json" });
    const c = siteCalibrationBody("pairs.csv", PAIRS);
    expect(c.pairs_csv).toBe(PAIRS);
    expect(c.document).toBeUndefined();
    expect(c.source_name).toBe("pairs.csv");
  });

  it("refuses what is neither, with the reason", () => {
    expect(() => siteCalibrationBody("a.json", "{ not json")).toThrow(/not valid JSON/);
    expect(() => siteCalibrationBody("a.json", '{"type": "FeatureCollection"}')).toThrow(/not a site calibration/);
    expect(() => siteCalibrationBody("points.csv", "name,easting_m,northing_m,height_m\nG1,1,2,3\n")).toThrow(/control pairs/);
    expect(() => siteCalibrationBody("empty.csv", "  \n")).toThrow(/empty/);
  });
});
