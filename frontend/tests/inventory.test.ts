import { describe, expect, it } from "vitest";
import { formatPm, inventoryCells, inventoryUrl, isIsoDate, materialLabel, todayUtc, type InventoryDoc } from "../src/lib/inventory";
import { fixtureText } from "./helpers";

// inventory_site.json: the JSON GET /sites/{id}/inventory serves for four piles on 2024-06-30, written by
// georef_core.deliverables.inventory (tests/frontend/test_inventory_fixture.py keeps it equal to the core's output)
const doc = JSON.parse(fixtureText("inventory_site.json")) as InventoryDoc;
const row = (name: string) => doc.stockpiles.find((r) => r.stockpile === name)!;

describe("stockpile inventory table", () => {
  it("writes a pile's volume, tonnes and change with their 1-sigma, as computed by hand", () => {
    const r = row("North pile"); // sand 100 ± 2 m³ (80 ± 1.5 a month before), default density 1.60 ± 0.10 t/m³
    expect(r.tonnes_t!).toBeCloseTo(1.6 * 100, 2);
    expect(r.tonnes_sigma_t!).toBeCloseTo(Math.hypot(1.6 * 2, 100 * 0.1), 2); // 10.50 t
    expect(r.change_sigma_m3!).toBeCloseTo(Math.hypot(2, 1.5), 2);
    const c = inventoryCells(r);
    expect(c.material).toBe("Sand");
    expect(c.surveyed).toBe("2024-06-01 · June flight");
    expect(c.volume).toEqual({ value: "100.0", pm: "± 2.0 (1σ)", ci95: "95 %: ± 3.9" });
    expect(c.density).toMatchObject({ value: "1.60", pm: "± 0.10 (1σ)" });
    expect(c.densityNote).toBe("default for sand");
    expect(c.tonnes).toMatchObject({ value: "160", pm: "± 11 (1σ)" }); // two significant digits of 10.5 (as served)
    expect(c.change).toMatchObject({ value: "+20.0", pm: "± 2.5 (1σ)" });
    expect(c.changeNote).toBe("since 2024-05-01");
  });

  it("names what is missing: a first survey, no density, no survey by the date", () => {
    const g = inventoryCells(row("Gravel bay"), new Map([["crushed_stone", "Crushed stone"]]));
    expect(g.volume).toMatchObject({ value: "1,523", pm: "± 12 (1σ)" });
    expect(g.tonnes).toMatchObject({ value: "2,894", pm: "± 80 (1σ)" });
    expect(g.density).toMatchObject({ value: "1.900", pm: "± 0.050 (1σ)" });
    expect([g.material, g.change.value, g.change.pm, g.changeNote]).toEqual(["Crushed stone", "–", "", "first survey"]);
    const w = inventoryCells(row("Wood chips"));
    expect([w.material, w.tonnes.value, w.densityNote]).toEqual(["wood chips", "–", "no density: volume only"]);
    expect(w.volume).toMatchObject({ value: "10.00", pm: "± 0.40 (1σ)" });
    const t = inventoryCells(row("Topsoil heap"));
    expect(t.measured).toBe(false);
    expect(t.status).toBe("no survey on or before 2024-06-30");
    expect(t.volume.value).toBe("–");
  });

  it("shows the server's totals: the sum, and independent sigmas in quadrature", () => {
    const measured = doc.stockpiles.filter((r) => r.volume_m3 !== null);
    expect(doc.totals.volume_m3!).toBeCloseTo(measured.reduce((a, r) => a + r.volume_m3!, 0), 6);
    expect(doc.totals.volume_sigma_m3!).toBeCloseTo(Math.hypot(...measured.map((r) => r.volume_sigma_m3!)), 2);
    const t = inventoryCells(doc.totals);
    expect(t.volume).toMatchObject({ value: "1,633", pm: "± 12 (1σ)" });
    expect(t.tonnes).toMatchObject({ value: "3,054", pm: "± 80 (1σ)" });
    expect(t.change).toMatchObject({ value: "+20.0", pm: "± 2.5 (1σ)" });
    expect(t.status).toBe("3 of 4 piles measured; tonnes of 2; change of 1");
  });

  it("formats values with their uncertainty", () => {
    expect(formatPm(-3.2, 0.18, { signed: true })).toEqual({ value: "-3.20", pm: "± 0.18 (1σ)", ci95: "" });
    expect(formatPm(-0.001, 0.13, { signed: true }).value).toBe("0.00"); // never "-0.00"
    expect(formatPm(15.2412, 0.013).value).toBe("15.24"); // at most 2 decimals: the server's rounding
    expect(formatPm(15.2412, 0).pm).toBe(""); // no uncertainty stored: nothing claimed
    expect(formatPm(null, 1)).toEqual({ value: "–", pm: "", ci95: "" });
    expect(materialLabel("asphalt_millings")).toBe("Asphalt millings");
    expect(materialLabel("Wood Chips")).toBe("Wood Chips");
  });

  it("asks for the chosen date and format; a non-date is not sent", () => {
    expect(inventoryUrl("site-1", "2024-06-30", "csv")).toBe("/api/v1/sites/site-1/inventory?date=2024-06-30&format=csv");
    expect(inventoryUrl("site-1", "2024-02-30", "xlsx")).toBe("/api/v1/sites/site-1/inventory?format=xlsx");
    expect([isIsoDate("2024-02-29"), isIsoDate("2023-02-29"), isIsoDate("30/06/2024"), isIsoDate("")]).toEqual([true, false, false, false]);
    expect(todayUtc(new Date("2024-06-30T23:30:00-02:00"))).toBe("2024-07-01"); // UTC, as the server's default
  });
});
