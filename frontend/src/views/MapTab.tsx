/** Map: orthophoto, shaded DSM with a colour ramp, the change since another survey, points, stockpiles. */

import { useEffect, useMemo, useState } from "preact/hooks";
import { api, apiUrl, mapLimit } from "../api/client";
import type { ApiPoint, Page, Run, Run as RunT, Stockpile, Survey } from "../api/types";
import { ColourLegend } from "../components/ColourLegend";
import { DesignLegend } from "../components/DesignLegend";
import { type MapOutline, MapView, type RasterLayer } from "../components/MapView";
import { ErrorBox, Note } from "../components/ui";
import { useLoad } from "../hooks";
import { openCog, readGrid, canvasOf } from "../lib/cog";
import { type BBox, type Ring, bboxOf, openRing } from "../lib/geom";
import { flightDate, formatVolume } from "../lib/format";
import { type Grid, RAMPS, difference, quantiles, renderHeights } from "../lib/raster";
import { autoRange, gridBBox, heightAt, useRunRaster } from "./rasterLayers";
import { useDesignLayer, useDesignSummary } from "./designLayer";
import { designClassOf } from "../lib/designClasses";
import { designAreaOutlines, type SiteDesign } from "../lib/designProgress";
import type { SurveyContext } from "./surveyContext";

export interface SiteRun {
  run: Run;
  survey: Survey;
}

/** Successful runs of every survey of the site (newest survey first): the "compare with" choices. */
export function useSiteRuns(siteId: string) {
  return useLoad(async (signal) => {
    const surveys = await api.get<Page<Survey>>(`/sites/${siteId}/surveys`, { query: { limit: 50 }, signal });
    const rows = await mapLimit(surveys.items, 4, async (s) => {
      const runs = await api.get<Page<RunT>>(`/surveys/${s.id}/runs`, { query: { state: "succeeded", limit: 1 }, signal });
      return runs.items[0] ? ({ run: runs.items[0], survey: s } as SiteRun) : null;
    });
    return rows.filter((x): x is SiteRun => x !== null);
  }, [siteId]);
}

export function pileOutlines(piles: Stockpile[] | undefined, selected?: string | null): MapOutline[] {
  return (piles ?? []).map((p) => ({
    id: p.id, name: p.name, kind: p.id === selected ? "selected" : "pile",
    ring: openRing((p.outline.coordinates[0] ?? []).map((c) => [c[0], c[1]] as [number, number])) as Ring,
  }));
}

export function MapTab({ ctx, run }: { ctx: SurveyContext; run: Run }) {
  const [showOrtho, setShowOrtho] = useState(true);
  const [showDsm, setShowDsm] = useState(false);
  const [ramp, setRamp] = useState<keyof typeof RAMPS>("terrain");
  const [shade, setShade] = useState(0.6);
  const [showPoints, setShowPoints] = useState(true);
  const [showPiles, setShowPiles] = useState(true);
  const [showArea, setShowArea] = useState(true);
  const [compareId, setCompareId] = useState("");
  const [dsmOpacity, setDsmOpacity] = useState(1);
  const designDone = useDesignSummary(run);
  const [showDesign, setShowDesign] = useState(false);
  const design = useDesignLayer(designDone ? run.id : null, showDesign);

  const dsmRange0 = useState<[number, number] | null>(null);
  const ortho = useRunRaster(run.id, "ortho", showOrtho);
  const needDsm = showDsm || !!compareId;
  const range = dsmRange0[0];
  const dsm = useRunRaster(run.id, "dsm", needDsm, range ? { min: range[0], max: range[1], ramp, shade } : undefined);
  useEffect(() => {
    const r = autoRange(dsm.grid);
    if (r && !range) dsmRange0[1](r);
  }, [dsm.grid]);

  const points = useLoad((signal) => api.get<ApiPoint[]>(`/surveys/${ctx.survey.id}/points`, { signal }).catch(() => [] as ApiPoint[]), [ctx.survey.id]);
  const piles = useLoad((signal) => api.get<Stockpile[]>(`/sites/${ctx.site.id}/stockpiles`, { signal }), [ctx.site.id]);
  // the site's design area (none: no design, or no area set yet)
  const siteDesign = useLoad((signal) => api.maybe<SiteDesign>(`/sites/${ctx.site.id}/design`, { signal }), [ctx.site.id]);
  const areaOutlines = designAreaOutlines(siteDesign.data);
  const siteRuns = useSiteRuns(ctx.site.id);
  const others = (siteRuns.data ?? []).filter((x) => x.run.id !== run.id);
  const change = useChange(dsm.grid, others.find((o) => o.run.id === compareId)?.run ?? null);

  const extent: BBox | null = useMemo(() => {
    const b = ortho.info?.bbox ?? dsm.info?.bbox ?? null;
    if (b) return b;
    const pts = (points.data ?? []).map((p) => [p.easting_m, p.northing_m] as [number, number]);
    const bb = bboxOf(pts);
    return bb ? { minX: bb.minX - 20, minY: bb.minY - 20, maxX: bb.maxX + 20, maxY: bb.maxY + 20 } : null;
  }, [ortho.info, dsm.info, points.data]);

  const rasters: RasterLayer[] = [];
  if (showOrtho) for (const l of [ortho.overview, ortho.detail]) if (l) rasters.push(l);
  if (showDsm) for (const l of [dsm.overview, dsm.detail]) if (l) rasters.push({ ...l, opacity: dsmOpacity });
  if (change.layer) rasters.push(change.layer);
  if (showDesign && design.layer) rasters.push(design.layer);

  const readout = (x: number, y: number) => {
    const parts: string[] = [];
    const h = heightAt([dsm.detailGrid, dsm.grid], x, y);
    if (h !== null) parts.push(`h ${h.toFixed(2)} m`);
    const d = change.grid ? heightAt([change.grid], x, y) : null;
    if (d !== null) parts.push(`Δh ${d >= 0 ? "+" : ""}${d.toFixed(2)} m`);
    if (showDesign && design.classes) {
      const cls = designClassOf(heightAt([design.classes], x, y) ?? NaN);
      const dd = design.difference ? heightAt([design.difference], x, y) : null;
      if (cls) parts.push(`to design ${dd !== null ? `${dd >= 0 ? "+" : ""}${dd.toFixed(2)} m ` : ""}(${cls.key.replace("_", " ")})`);
    }
    return parts.join("  ") || null;
  };

  return (
    <div class="map-tab">
      <div class="layer-panel" role="group" aria-label="Layers">
        <label><input type="checkbox" checked={showOrtho} onChange={() => setShowOrtho(!showOrtho)} /> Orthophoto</label>
        <label><input type="checkbox" checked={showDsm} onChange={() => setShowDsm(!showDsm)} /> Surface model (DSM)</label>
        {showDsm ? (
          <span class="sub-controls">
            <label>colours <select value={ramp} onChange={(e) => setRamp((e.target as HTMLSelectElement).value as keyof typeof RAMPS)}>
              <option value="terrain">terrain</option><option value="viridis">viridis</option>
            </select></label>
            <label>hillshade <input type="range" min="0" max="1" step="0.1" value={shade} onInput={(e) => setShade(Number((e.target as HTMLInputElement).value))} aria-valuetext={`${Math.round(shade * 100)} %`} /></label>
            <label>opacity <input type="range" min="0.2" max="1" step="0.1" value={dsmOpacity} onInput={(e) => setDsmOpacity(Number((e.target as HTMLInputElement).value))} aria-valuetext={`${Math.round(dsmOpacity * 100)} %`} /></label>
            {range ? (
              <>
                <label>from <input type="number" step="0.5" class="short" value={range[0].toFixed(1)} onChange={(e) => dsmRange0[1]([Number((e.target as HTMLInputElement).value), range[1]])} /> m</label>
                <label>to <input type="number" step="0.5" class="short" value={range[1].toFixed(1)} onChange={(e) => dsmRange0[1]([range[0], Number((e.target as HTMLInputElement).value)])} /> m</label>
                <button type="button" class="link small" onClick={() => dsmRange0[1](autoRange(dsm.grid))}>auto</button>
              </>
            ) : null}
          </span>
        ) : null}
        <label>Change since{" "}
          <select value={compareId} onChange={(e) => setCompareId((e.target as HTMLSelectElement).value)} aria-label="Compare the surface with another survey">
            <option value="">—</option>
            {others.map((o) => <option key={o.run.id} value={o.run.id}>{o.survey.name} (flown {flightDate(o.survey).text})</option>)}
          </select>
        </label>
        {designDone ? <label><input type="checkbox" checked={showDesign} onChange={() => setShowDesign(!showDesign)} /> Cut/fill to design</label> : null}
        <label><input type="checkbox" checked={showPoints} onChange={() => setShowPoints(!showPoints)} /> Ground points</label>
        <label><input type="checkbox" checked={showPiles} onChange={() => setShowPiles(!showPiles)} /> Stockpiles</label>
        {areaOutlines.length ? <label><input type="checkbox" checked={showArea} onChange={() => setShowArea(!showArea)} /> Design area</label> : null}
      </div>
      <ErrorBox error={showOrtho ? ortho.error : null} title="Orthophoto" />
      <ErrorBox error={needDsm ? dsm.error : null} title="Surface model" />
      <ErrorBox error={change.error} title="Change map" />
      <ErrorBox error={showDesign ? design.error : null} title="Cut/fill to design" />
      {(ortho.loading || dsm.loading || change.loading || design.loading) ? <p class="small muted" aria-live="polite">Loading rasters…</p> : null}
      <MapView
        label={`Map of ${ctx.survey.name}`}
        extent={extent}
        rasters={rasters}
        points={showPoints ? (points.data ?? []).map((p) => ({ name: p.name, x: p.easting_m, y: p.northing_m, role: p.role })) : []}
        outlines={[...(showArea ? areaOutlines : []), ...(showPiles ? pileOutlines(piles.data) : [])]}
        onView={(b, ppm) => { ortho.viewChanged(b, ppm); dsm.viewChanged(b, ppm); }}
        readout={readout}
        height={520}
        legend={
          <>
            {showDsm && range ? <ColourLegend ramp={ramp} min={range[0]} max={range[1]} unit="m" label="Height (ellipsoidal)" /> : null}
            {change.range ? <ColourLegend ramp="diverging" min={-change.range} max={change.range} unit="m" label="Height change (blue lower, red higher)" /> : null}
            {showDesign && designDone ? <DesignLegend summary={designDone} /> : null}
            {change.stats ? <p class="small">Against {others.find((o) => o.run.id === compareId)?.survey.name}: {formatVolume(change.stats.gained)} gained, {formatVolume(change.stats.lost)} lost over {Math.round(change.stats.area).toLocaleString("en-GB")} m² compared (at the overview resolution).</p> : null}
          </>
        }
      />
      {!ortho.info && !dsm.info && !ortho.loading && !dsm.loading && (ortho.error || dsm.error) ? <Note>This run has no orthophoto or surface model (the dense step did not run or failed).</Note> : null}
    </div>
  );
}

/** Height change of the current DSM against another run's DSM, on the current grid. */
export function useChange(current: Grid | null, other: Run | null) {
  const [st, setSt] = useState<{ layer: RasterLayer | null; grid: Grid | null; range: number | null; stats: { gained: number; lost: number; area: number } | null; error: Error | null; loading: boolean }>({ layer: null, grid: null, range: null, stats: null, error: null, loading: false });
  useEffect(() => {
    setSt({ layer: null, grid: null, range: null, stats: null, error: null, loading: false });
    if (!current || !other) return;
    const ac = new AbortController();
    setSt((s) => ({ ...s, loading: true }));
    (async () => {
      try {
        const info = await openCog(apiUrl(`/runs/${other.id}/results/dsm`));
        const b = gridBBox(current);
        const earlier = await readGrid(info, { bbox: b, width: current.width, height: current.height }, ac.signal);
        const d = difference(current, earlier);
        const [lo, hi] = quantiles(d.data, [0.02, 0.98]);
        const range = Math.max(0.05, Math.abs(lo), Math.abs(hi));
        const rgba = renderHeights(d, { min: -range, max: range, ramp: "diverging", shade: 0 });
        let gained = 0, lost = 0, n = 0;
        const cell = d.resX * d.resY;
        for (const v of d.data) {
          if (!Number.isFinite(v)) continue;
          n++;
          if (v > 0) gained += v * cell;
          else lost -= v * cell;
        }
        if (!ac.signal.aborted) setSt({ layer: { id: "change", canvas: canvasOf(rgba, d.width, d.height), bbox: gridBBox(d), opacity: 0.85 }, grid: d, range, stats: { gained, lost, area: n * cell }, error: null, loading: false });
      } catch (e) {
        if (!ac.signal.aborted) setSt({ layer: null, grid: null, range: null, stats: null, error: e as Error, loading: false });
      }
    })();
    return () => ac.abort();
  }, [current, other?.id]);
  return st;
}
