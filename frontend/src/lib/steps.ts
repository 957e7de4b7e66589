/** The processing steps as the server declares them (GET /api/v1/steps, georef_core.steps.contract): the
 * settings form and the downloads list are built from these specs, not from lists kept here. */

import { api } from "../api/client";

export interface JsonSchemaProp {
  type?: string;
  enum?: string[];
  minimum?: number;
  maximum?: number;
  minItems?: number;
  items?: { type?: string; minimum?: number; maximum?: number };
  anyOf?: JsonSchemaProp[];
  default?: unknown;
  description?: string;
  "x-unit"?: string;
  "x-advanced"?: boolean;
}

export interface StepProduct {
  endpoint: string;
  title: string;
  description: string;
  needs: string[];
  formats: [string, string][];
}

export interface StepSpec {
  name: string;
  title: string;
  description: string;
  version: number;
  depends_on: string[];
  options_schema: { properties: Record<string, JsonSchemaProp> };
  outputs: { key: string; path: string; description: string; media_type: string | null }[];
  products: StepProduct[];
}

export interface SettingField {
  section: string; // the step
  key: string; // the option
  label: string; // its help text
  kind: "choice" | "bool" | "number" | "integer" | "text" | "numbers" | "object";
  options?: string[];
  minimum?: number;
  maximum?: number;
  unit?: string;
  default?: unknown;
  advanced: boolean;
}

let cache: Promise<StepSpec[]> | null = null;

/** The step specs, fetched once per page load. */
export function loadSteps(signal?: AbortSignal): Promise<StepSpec[]> {
  if (!cache) {
    cache = api.get<{ items: StepSpec[] }>("/steps", { signal }).then((r) => r.items);
    cache.catch(() => { cache = null; });
  }
  return cache;
}

function base(p: JsonSchemaProp): JsonSchemaProp {
  // nullable options are {anyOf: [schema, {type: "null"}]} with default/description beside
  const inner = p.anyOf?.find((s) => s.type !== "null");
  return inner ? { ...inner, ...p, anyOf: undefined, type: inner.type } : p;
}

/** Every option of every step as a form field, in the specs' order. */
export function settingFields(specs: StepSpec[]): SettingField[] {
  const out: SettingField[] = [];
  for (const s of specs) {
    for (const [key, raw] of Object.entries(s.options_schema.properties)) {
      const p = base(raw);
      const kind: SettingField["kind"] = p.enum ? "choice" : p.type === "boolean" ? "bool" : p.type === "number" ? "number"
        : p.type === "integer" ? "integer" : p.type === "array" ? "numbers" : p.type === "object" ? "object" : "text";
      out.push({
        section: s.name, key, label: p.description || key, kind, options: p.enum,
        minimum: p.minimum ?? p.items?.minimum, maximum: p.maximum ?? p.items?.maximum, unit: p["x-unit"],
        default: p.default, advanced: Boolean(p["x-advanced"]),
      });
    }
  }
  return out;
}

/** The downloads: every step's products, the accuracy report first. */
export function productsOf(specs: StepSpec[]): StepProduct[] {
  const all = specs.flatMap((s) => s.products);
  return [...all.filter((p) => p.endpoint === "report.pdf"), ...all.filter((p) => p.endpoint !== "report.pdf")];
}

/** A form value parsed for its field (numbers, booleans); undefined when empty (the step's default). */
export function parseSetting(f: SettingField, text: string): unknown {
  const t = text.trim();
  if (t === "") return undefined;
  if (f.kind === "bool") return t === "true";
  if (f.kind === "number" || f.kind === "integer") {
    const v = Number(t);
    if (!Number.isFinite(v) || (f.kind === "integer" && !Number.isInteger(v))) throw new Error(`${f.section}.${f.key}: ${t} is not a${f.kind === "integer" ? " whole" : ""} number`);
    if (f.minimum !== undefined && v < f.minimum) throw new Error(`${f.section}.${f.key}: ${v} is below the minimum ${f.minimum}`);
    if (f.maximum !== undefined && v > f.maximum) throw new Error(`${f.section}.${f.key}: ${v} is above the maximum ${f.maximum}`);
    return v;
  }
  if (f.kind === "numbers" || f.kind === "object") {
    try {
      return JSON.parse(t);
    } catch {
      throw new Error(`${f.section}.${f.key}: not valid JSON`);
    }
  }
  return t;
}
