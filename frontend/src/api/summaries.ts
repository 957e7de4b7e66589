/**
 * Key figures of a survey and a site for the overview pages, composed from the plain REST resources
 * (latest run, its check-point residuals and its stockpile volumes).
 */

import { statsFromServed, type ResidualStats } from "../lib/residuals";
import { api, mapLimit } from "./client";
import type { Page, ResidualsResponse, Run, RunVolume, Site, Survey } from "./types";

export interface SurveySummary {
  survey: Survey;
  latestRun: Run | null;
  lastGoodRun: Run | null;
  stats: ResidualStats | null;
  checkPoints: number;
  volumes: RunVolume[] | null;
}

export interface SiteSummary {
  site: Site;
  surveys: number;
  latest: SurveySummary | null;
}

export function residualRows(r: ResidualsResponse | null) {
  return (r?.points ?? [])
    .filter((p) => p.dx_m !== null && p.dy_m !== null && p.dz_m !== null)
    .map((p) => ({ ...p, role: String(p.role ?? "check"), name: String(p.name) }));
}

/** Rows of the residual table that are independent check points (not the adjustment's control). */
export function checkRows(r: ResidualsResponse | null) {
  const rows = residualRows(r);
  const checks = rows.filter((p) => p.role.startsWith("check"));
  return checks.length || !rows.length ? checks : rows.filter((p) => !p.role.startsWith("control"));
}

export async function surveySummary(survey: Survey, signal?: AbortSignal): Promise<SurveySummary> {
  const runs = await api.get<Page<Run>>(`/surveys/${survey.id}/runs`, { query: { limit: 10 }, signal });
  const latestRun = runs.items[0] ?? null;
  const lastGoodRun = runs.items.find((r) => r.state === "succeeded") ?? null;
  let stats: ResidualStats | null = null;
  let checkPoints = 0;
  let volumes: RunVolume[] | null = null;
  if (lastGoodRun) {
    const [res, vol] = await Promise.all([
      api.maybe<ResidualsResponse>(`/runs/${lastGoodRun.id}/results/residuals`, { signal }),
      api.maybe<{ stockpiles: RunVolume[] }>(`/runs/${lastGoodRun.id}/results/volumes`, { signal }),
    ]);
    const rows = checkRows(res);
    stats = statsFromServed(res?.stats);
    checkPoints = rows.length;
    volumes = vol?.stockpiles ?? null;
  }
  return { survey, latestRun, lastGoodRun, stats, checkPoints, volumes };
}

export async function siteSummary(site: Site, signal?: AbortSignal): Promise<SiteSummary> {
  const page = await api.get<Page<Survey>>(`/sites/${site.id}/surveys`, { query: { limit: 1 }, signal });
  const latest = page.items[0] ? await surveySummary(page.items[0], signal) : null;
  return { site, surveys: page.total, latest };
}

export async function siteSummaries(sites: Site[], signal?: AbortSignal): Promise<SiteSummary[]> {
  return mapLimit(sites, 4, (s) => siteSummary(s, signal));
}

export function totalVolume(v: RunVolume[] | null): number | null {
  if (!v || !v.length) return null;
  return v.reduce((a, x) => a + (x.volume_m3 ?? 0), 0);
}
