import { describe, expect, it } from "vitest";
import { parseSetting, productsOf, settingFields, type StepSpec } from "../src/lib/steps";
import fixture from "./fixtures/steps_with_toy.json";

// GET /api/v1/steps as the server answers it with the toy plug-in step of tests/steps/toy_step.py registered
// (tests/steps/test_step_contract.py keeps this file equal to the server's answer)
const specs = (fixture as { items: StepSpec[] }).items;

describe("the settings form and downloads come from the served step specs", () => {
  it("lists a step's options, toy step included, with kinds, choices and ranges", () => {
    const fields = settingFields(specs);
    const toy = fields.filter((f) => f.section === "toy");
    expect(toy.map((f) => f.key)).toEqual(["greeting", "repeat"]);
    expect(toy[0]).toMatchObject({ kind: "choice", options: ["hello", "hi"], default: "hello" });
    expect(toy[1]).toMatchObject({ kind: "integer", minimum: 1, maximum: 5, default: 1 });
    const freq = fields.find((f) => f.section === "gnss" && f.key === "freq")!;
    expect(freq.options).toEqual(["auto", "l1", "l1+l2", "l1+l2+l5"]);
    const cam = fields.find((f) => f.section === "georef" && f.key === "camera_model")!;
    expect(cam).toMatchObject({ kind: "choice", advanced: false });
    expect(fields.find((f) => f.key === "elmask")).toMatchObject({ kind: "number", unit: "deg", minimum: 0, maximum: 60 });
  });

  it("lists every step's downloads, the report first and the toy step's file", () => {
    const products = productsOf(specs);
    expect(products[0].endpoint).toBe("report.pdf");
    const toy = products.find((p) => p.title === "Toy greeting")!;
    expect(toy.needs).toEqual(["toy/hello.txt"]);
    expect(products.find((p) => p.endpoint === "camera-positions")!.needs).toEqual(["ppk/events.csv"]);
    expect(products.find((p) => p.endpoint === "point-cloud")!.needs).toEqual(["dense/points.laz"]);
  });

  it("parses form values by the option's kind and range", () => {
    const repeat = settingFields(specs).find((f) => f.section === "toy" && f.key === "repeat")!;
    expect(parseSetting(repeat, "3")).toBe(3);
    expect(parseSetting(repeat, "")).toBeUndefined();
    expect(() => parseSetting(repeat, "9")).toThrow(/above the maximum 5/);
    expect(() => parseSetting(repeat, "2.5")).toThrow(/not a whole number/);
  });
});
