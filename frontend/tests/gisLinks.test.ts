import { readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { describe, expect, it } from "vitest";
import { clampTokenDays, expiryText, wmtsCapabilitiesUrl, xyzUrl } from "../src/lib/gisLinks";

const repo = join(dirname(fileURLToPath(import.meta.url)), "..", "..");

describe("GIS links of a run's tiles", () => {
  it("puts the tile token on the WMTS document and the XYZ templates, on the page's origin", () => {
    const layer = { tiles: "http://10.0.0.5:8000/api/v1/runs/r-1/tiles/ortho/{z}/{x}/{y}.png" }; // the server's own origin
    expect(xyzUrl("https://georef.example.com", layer, "grf_AbC")).toBe("https://georef.example.com/api/v1/runs/r-1/tiles/ortho/{z}/{x}/{y}.png?token=grf_AbC");
    expect(wmtsCapabilitiesUrl("https://georef.example.com/", "r-1", "grf_a+b/c=")).toBe(
      "https://georef.example.com/api/v1/runs/r-1/wmts/1.0.0/WMTSCapabilities.xml?token=grf_a%2Bb%2Fc%3D",
    );
  });

  it("asks the paths the API serves (backend/api/routes/tiles.py)", () => {
    const routes = readFileSync(join(repo, "backend", "api", "routes", "tiles.py"), "utf8");
    expect(routes).toContain('prefix="/runs/{run_id}"');
    expect(routes).toContain('"/wmts/1.0.0/WMTSCapabilities.xml"');
    expect(routes).toContain('"/tiles/{layer}/{z}/{x}/{y}.png"');
  });

  it("says when the token expires, and keeps its life within 1 to 90 days", () => {
    const now = new Date("2024-06-30T12:00:00Z");
    expect(expiryText("2024-07-30T12:00:00Z", now)).toBe("expires 2024-07-30 12:00 UTC (in 30 days)");
    expect(expiryText("2024-06-30T17:00:00Z", now)).toBe("expires 2024-06-30 17:00 UTC (in 5 hours)");
    expect(expiryText("2024-06-29T12:00:00Z", now)).toBe("has expired");
    expect(expiryText(null, now)).toBe("does not expire");
    expect([clampTokenDays(0), clampTokenDays(200), clampTokenDays(7.4), clampTokenDays(NaN)]).toEqual([1, 90, 7, 30]);
  });
});
