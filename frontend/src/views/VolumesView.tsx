/**
 * Volumes: outline a stockpile (draw on the map, import GeoJSON, or type coordinates), choose the base,
 * read cut / fill / net ± uncertainty; the server measures saved stockpiles in every run (volumes step),
 * which gives each pile's volume over time. The change map compares this surface with another survey.
 */

import { useEffect, useState } from "preact/hooks";
import { api } from "../api/client";
import type { OutlineVolume, Run, RunDetail, RunVolume, Stockpile, VolumePoint } from "../api/types";
import { ColourLegend } from "../components/ColourLegend";
import { LineChart } from "../components/LineChart";
import { MapView, type RasterLayer } from "../components/MapView";
import { ErrorBox, Note } from "../components/ui";
import { useLoad } from "../hooks";
import { flightDate, formatArea, formatVolume, formatVolumePm } from "../lib/format";
import { type Ring, area, outlinesFromGeoJson, ringToGeoJson, selfIntersects } from "../lib/geom";
import { showRun } from "./startRun";
import { pileOutlines, useChange, useSiteRuns } from "./MapTab";
import { autoRange, heightAt, useRunRaster } from "./rasterLayers";
import type { SurveyContext } from "./surveyContext";

const BASES = [
  ["plane", "Best-fit plane through the outline (recommended)"],
  ["lowest", "Lowest point of the outline (2nd percentile)"],
  ["highest", "Highest point of the outline"],
  ["mean", "Mean height of the outline"],
  ["tin", "Triangulated outline (server only)"],
  ["elevation", "A fixed elevation"],
] as const;

function baseText(kind: string, z: string): string {
  return kind === "elevation" ? `elevation:${Number(z)}` : kind;
}

/**
 * The volume of an outline as the server measures it (POST /runs/{id}/volumes: the volumes step's own
 * computation on the run's DSM, nothing saved), so what is shown before saving is what the stockpile gets.
 */
export function outlineVolume(runId: string, ring: Ring, base: string, signal?: AbortSignal): Promise<OutlineVolume> {
  return api.post<OutlineVolume>(`/runs/${runId}/volumes`, { outline: ringToGeoJson(ring), base }, { signal });
}

export function VolumesView({ ctx, run }: { ctx: SurveyContext; run: Run }) {
  const [draft, setDraft] = useState<Ring>([]);
  const [closed, setClosed] = useState(false);
  const [drawing, setDrawing] = useState(false);
  const [baseKind, setBaseKind] = useState("plane");
  const [baseZ, setBaseZ] = useState("");
  const [name, setName] = useState("");
  const [material, setMaterial] = useState("");
  const [density, setDensity] = useState("");
  const [selected, setSelected] = useState<string | null>(null);
  const [showDsm, setShowDsm] = useState(false);
  const [compareId, setCompareId] = useState("");
  const [error, setError] = useState<Error | null>(null);
  const [busy, setBusy] = useState(false);
  const [quick, setQuick] = useState<OutlineVolume | null>(null);
  const [quickErr, setQuickErr] = useState<string | null>(null);
  const [coordText, setCoordText] = useState("");

  const ortho = useRunRaster(run.id, "ortho", true);
  const range = useState<[number, number] | null>(null);
  const dsm = useRunRaster(run.id, "dsm", true, range[0] ? { min: range[0][0], max: range[0][1], ramp: "terrain", shade: 0.6 } : undefined);
  useEffect(() => {
    if (!range[0] && dsm.grid) range[1](autoRange(dsm.grid));
  }, [dsm.grid]);
  const piles = useLoad((signal) => api.get<Stockpile[]>(`/sites/${ctx.site.id}/stockpiles`, { signal }), [ctx.site.id]);
  const runVolumes = useLoad((signal) => api.maybe<{ stockpiles: RunVolume[] }>(`/runs/${run.id}/results/volumes`, { signal }), [run.id]);
  const history = useLoad(async (signal) => (selected ? api.get<VolumePoint[]>(`/stockpiles/${selected}/volumes`, { signal }) : null), [selected]);
  const siteRuns = useSiteRuns(ctx.site.id);
  const others = (siteRuns.data ?? []).filter((x) => x.run.id !== run.id);
  const change = useChange(compareId ? dsm.grid : null, others.find((o) => o.run.id === compareId)?.run ?? null);

  // The volume of the outline before it is saved: measured by the server, as the saved stockpile will be.
  useEffect(() => {
    setQuick(null);
    setQuickErr(null);
    if (!closed || draft.length < 3) return;
    if (baseKind === "elevation" && (baseZ.trim() === "" || !Number.isFinite(Number(baseZ)))) return;
    if (selfIntersects(draft)) {
      setQuickErr("the outline crosses itself");
      return;
    }
    const ac = new AbortController();
    outlineVolume(run.id, draft, baseText(baseKind, baseZ), ac.signal)
      .then((v) => { if (!ac.signal.aborted) setQuick(v); })
      .catch((e) => { if (!ac.signal.aborted) setQuickErr((e as Error).message); });
    return () => ac.abort();
  }, [closed, draft, baseKind, baseZ, run.id]);

  const extent = ortho.info?.bbox ?? dsm.info?.bbox ?? null;
  const rasters: RasterLayer[] = [];
  for (const l of [ortho.overview, ortho.detail]) if (l) rasters.push(l);
  if (showDsm) for (const l of [dsm.overview, dsm.detail]) if (l) rasters.push({ ...l, opacity: 0.8 });
  if (change.layer) rasters.push(change.layer);

  const startDraw = () => {
    setDraft([]);
    setClosed(false);
    setDrawing(true);
    setSelected(null);
  };
  const closeDraft = () => {
    if (draft.length < 3) return;
    setDrawing(false);
    setClosed(true);
  };
  const importFile = async (f: File) => {
    setError(null);
    try {
      const outlines = outlinesFromGeoJson(await f.text());
      const o = outlines[0];
      setDraft(o.ring);
      setClosed(true);
      setDrawing(false);
      if (!name) setName(o.name);
      if (outlines.length > 1) setError(new Error(`${outlines.length} polygons in the file: the first (“${o.name}”) is shown; save it, then import the next.`));
    } catch (e) {
      setError(e as Error);
    }
  };
  const applyCoords = () => {
    const ring: Ring = coordText.split(/\n/).map((l) => l.trim()).filter(Boolean).map((l) => l.split(/[\s,;]+/).map(Number) as unknown as [number, number]).filter((p) => Number.isFinite(p[0]) && Number.isFinite(p[1]));
    if (ring.length < 3) {
      setError(new Error("At least three lines of “easting northing” are needed."));
      return;
    }
    setError(null);
    setDraft(ring.map((p) => [p[0], p[1]]));
    setClosed(true);
    setDrawing(false);
  };

  const save = async (e: Event) => {
    e.preventDefault();
    setBusy(true);
    setError(null);
    try {
      if (selfIntersects(draft)) throw new Error("The outline crosses itself: redraw it.");
      const sp = await api.post<Stockpile>(`/sites/${ctx.site.id}/stockpiles`, {
        name: name.trim(), outline: ringToGeoJson(draft), base: baseText(baseKind, baseZ), material: material.trim(),
        density_t_m3: density ? Number(density) : null,
      });
      piles.reload();
      setSelected(sp.id);
      setDraft([]);
      setClosed(false);
      setName("");
    } catch (err) {
      setError(err as Error);
    } finally {
      setBusy(false);
    }
  };

  const measure = async () => {
    setBusy(true);
    setError(null);
    try {
      const r = await api.post<RunDetail>(`/runs/${run.id}/rerun`, { from_step: "volumes", settings: {} });
      showRun(ctx, r.id);
    } catch (err) {
      setError(err as Error);
    } finally {
      setBusy(false);
    }
  };

  const removePile = async (p: Stockpile) => {
    if (!confirm(`Delete the stockpile “${p.name}” and its outline? Its measured history stays in the runs.`)) return;
    try {
      await api.del(`/stockpiles/${p.id}`);
      if (selected === p.id) setSelected(null);
      piles.reload();
    } catch (err) {
      setError(err as Error);
    }
  };

  const vols = runVolumes.data?.stockpiles ?? [];
  const unmeasured = (piles.data ?? []).filter((p) => !vols.some((v) => v.stockpile_id === p.id));
  const selPile = piles.data?.find((p) => p.id === selected) ?? null;
  const outlines = [...pileOutlines(piles.data, selected), ...(closed && draft.length >= 3 ? [{ id: "draft", name: name || "new outline", ring: draft, kind: "draft" as const }] : [])];

  return (
    <div class="volumes two-col wide-left">
      <div>
        <div class="layer-panel" role="group" aria-label="Layers">
          <label><input type="checkbox" checked={showDsm} onChange={() => setShowDsm(!showDsm)} /> Shaded surface model</label>
          <label>Change since{" "}
            <select value={compareId} onChange={(e) => setCompareId((e.target as HTMLSelectElement).value)}>
              <option value="">—</option>
              {others.map((o) => <option key={o.run.id} value={o.run.id}>{o.survey.name} (flown {flightDate(o.survey).text})</option>)}
            </select>
          </label>
          {/* the same width in both states, and the drawing's hint and Cancel inside the map: nothing above
              the map changes size when drawing starts, so the map never moves under the cursor */}
          {ctx.canEdit ? <button type="button" class={drawing ? "primary draw-toggle" : "secondary draw-toggle"} onClick={drawing ? closeDraft : startDraw} aria-pressed={drawing}>{drawing ? `Finish outline (${draft.length} corners)` : "Draw an outline"}</button> : null}
        </div>
        <ErrorBox error={dsm.error} title="Surface model" />
        <ErrorBox error={change.error} title="Change map" />
        <MapView
          label="Stockpile map"
          extent={extent}
          rasters={rasters}
          outlines={outlines}
          drawing={drawing ? {
            ring: draft,
            onAdd: (p) => setDraft((d) => [...d, p]),
            onClose: closeDraft,
            onUndo: () => setDraft((d) => d.slice(0, -1)),
            onCancel: () => { setDrawing(false); setDraft([]); },
          } : null}
          onSelectOutline={(id) => id !== "draft" && !drawing && setSelected(id)}
          overlay={drawing ? (
            <>
              <span class="small" aria-live="polite">Click the corners of the pile's toe (or focus the map and press Space at the centre cross); double-click or Enter to finish, Backspace removes the last corner.</span>
              <button type="button" class="ghost small" onClick={() => { setDrawing(false); setDraft([]); }}>Cancel</button>
            </>
          ) : null}
          onView={(b, ppm) => { ortho.viewChanged(b, ppm); dsm.viewChanged(b, ppm); }}
          readout={(x, y) => {
            const h = heightAt([dsm.detailGrid, dsm.grid], x, y);
            const d = change.grid ? heightAt([change.grid], x, y) : null;
            return [h !== null ? `h ${h.toFixed(2)} m` : "", d !== null ? `Δh ${d >= 0 ? "+" : ""}${d.toFixed(2)} m` : ""].join("  ").trim() || null;
          }}
          height={500}
          legend={<>
            {change.range ? <ColourLegend ramp="diverging" min={-change.range} max={change.range} unit="m" label="Height change (blue lower, red higher)" /> : null}
            {change.stats ? <p class="small">{formatVolume(change.stats.gained)} gained, {formatVolume(change.stats.lost)} lost over {formatArea(change.stats.area)} compared.</p> : null}
          </>}
        />
        {!dsm.info && !dsm.loading && dsm.error ? <Note>Volumes need the surface model of this run (dense step).</Note> : null}
      </div>

      <div>
        {ctx.canEdit ? (
          <section class="card" aria-labelledby="outline-title">
            <h2 id="outline-title" class="h3">New stockpile</h2>
            <div class="actions">
              <label class="button secondary small">Import GeoJSON…
                <input type="file" accept=".geojson,.json,application/geo+json,application/json" class="visually-hidden-input" onChange={(e) => { const f = (e.target as HTMLInputElement).files?.[0]; if (f) importFile(f); (e.target as HTMLInputElement).value = ""; }} />
              </label>
            </div>
            <details>
              <summary class="small">Type the corner coordinates</summary>
              <label for="coords" class="small">One corner per line: easting northing ({ctx.site.crs})</label>
              <textarea id="coords" rows={4} value={coordText} onInput={(e) => setCoordText((e.target as HTMLTextAreaElement).value)} />
              <button type="button" class="secondary small" onClick={applyCoords}>Use these corners</button>
            </details>
            {closed && draft.length >= 3 ? (
              <form onSubmit={save} aria-label="Save the stockpile">
                <p class="small">Outline: {draft.length} corners, {formatArea(area(draft))}{selfIntersects(draft) ? " — crosses itself!" : ""}</p>
                <div class="field">
                  <label for="base-kind">Base (what the volume is measured above)</label>
                  <select id="base-kind" value={baseKind} onChange={(e) => setBaseKind((e.target as HTMLSelectElement).value)}>
                    {BASES.map(([k, l]) => <option key={k} value={k}>{l}</option>)}
                  </select>
                </div>
                {baseKind === "elevation" ? (
                  <div class="field">
                    <label for="base-z">Base elevation (m, ellipsoidal like the DSM)</label>
                    <input id="base-z" type="number" step="0.01" required value={baseZ} onInput={(e) => setBaseZ((e.target as HTMLInputElement).value)} />
                  </div>
                ) : null}
                <QuickResult q={quick} err={quickErr} loading={closed && !quick && !quickErr} />
                <div class="field">
                  <label for="pile-name">Name</label>
                  <input id="pile-name" required value={name} onInput={(e) => setName((e.target as HTMLInputElement).value)} />
                </div>
                <div class="form-grid">
                  <div class="field">
                    <label for="pile-material">Material</label>
                    <input id="pile-material" value={material} onInput={(e) => setMaterial((e.target as HTMLInputElement).value)} />
                  </div>
                  <div class="field">
                    <label for="pile-density">Density (t/m³)</label>
                    <input id="pile-density" type="number" step="0.01" min="0.1" max="29" value={density} onInput={(e) => setDensity((e.target as HTMLInputElement).value)} />
                  </div>
                </div>
                <div class="actions">
                  <button type="submit" class="primary" disabled={busy}>Save stockpile</button>
                  <button type="button" class="ghost" onClick={() => { setDraft([]); setClosed(false); }}>Discard</button>
                </div>
              </form>
            ) : !drawing ? <p class="small muted">Draw an outline on the map, import a GeoJSON polygon ({ctx.site.crs}) or type its corners.</p> : null}
            <ErrorBox error={error} />
          </section>
        ) : <ErrorBox error={error} />}

        <section aria-labelledby="piles-title">
          <h2 id="piles-title" class="h3">Stockpiles in run {run.number}</h2>
          {piles.data && !piles.data.length ? <p class="muted small">No stockpile on this site yet.</p> : null}
          {vols.length ? (
            <div class="table-wrap">
              <table class="data compact" data-testid="volume-table">
                <thead><tr><th scope="col">Pile</th><th scope="col">Base</th><th scope="col" class="num">Cut</th><th scope="col" class="num">Fill</th><th scope="col" class="num">Net</th><th scope="col" class="num">Area</th></tr></thead>
                <tbody>
                  {vols.map((v) => (
                    <tr key={v.name} class={v.stockpile_id === selected ? "selected" : ""}>
                      <th scope="row"><button type="button" class="link" onClick={() => setSelected(v.stockpile_id)}>{v.name}</button></th>
                      <td>{v.base}</td>
                      <td class="num">{formatVolume(v.cut_m3, v.sigma_m3)}</td>
                      <td class="num">{formatVolume(v.fill_m3, v.sigma_m3)}</td>
                      <td class="num"><strong>{formatVolumePm(v.volume_m3, v.sigma_m3)}</strong></td>
                      <td class="num">{formatArea(v.area_m2)}</td>
                    </tr>
                  ))}
                </tbody>
              </table>
            </div>
          ) : null}
          {unmeasured.length ? (
            <>
              <p class="small">Not measured in this run: {unmeasured.map((p) => p.name).join(", ")}.</p>
              {ctx.canEdit ? <button type="button" class="secondary" onClick={measure} disabled={busy}>Measure saved stockpiles on this survey</button> : null}
            </>
          ) : null}
        </section>

        {selPile ? (
          <section aria-labelledby="hist-title">
            <h2 id="hist-title" class="h3">{selPile.name} over time</h2>
            <p class="small muted">Base {selPile.base}{selPile.material ? ` · ${selPile.material_label || selPile.material}` : ""}{selPile.density_t_m3 ? ` · ${selPile.density_t_m3} t/m³` : ""} · {formatArea(area(pileOutlines([selPile])[0].ring))}</p>
            {history.data ? (
              <LineChart title={`Net volume of ${selPile.name}`} yLabel="m³" xTime yZero
                series={[{ name: selPile.name, colour: "#1f6feb", markers: true, points: history.data.filter((h) => h.volume_m3 !== null).map((h) => ({ x: Date.parse(h.measured_at ?? "") || 0, y: h.volume_m3, err: h.sigma_m3 ?? null, label: `${h.survey_name} (run ${h.run_number})` })) }]}
                yFormat={(v) => Math.round(v).toLocaleString("en-GB")} />
            ) : null}
            {ctx.canEdit ? <button type="button" class="link danger small" onClick={() => removePile(selPile)}>Delete this stockpile</button> : null}
          </section>
        ) : null}
      </div>
    </div>
  );
}

function QuickResult({ q, err, loading }: { q: OutlineVolume | null; err: string | null; loading: boolean }) {
  if (err) return <Note kind="warning">No volume: {err}.</Note>;
  if (loading) return <p class="small muted" aria-live="polite">Measuring on the surface model…</p>;
  if (!q) return null;
  const sigma = q.uncertainty?.sigma_m3 ?? null;
  const net = q.volume_m3 ?? q.net_m3;
  const b = typeof q.base === "object" && q.base ? q.base : {};
  const baseZ = typeof b.elevation_m === "number" ? b.elevation_m : typeof b.z_ref_m === "number" ? b.z_ref_m : null;
  return (
    <div class="quick" aria-live="polite" data-testid="quick-volume">
      <dl class="figures-inline">
        <div><dt>Cut (above base)</dt><dd data-value={q.cut_m3}>{formatVolume(q.cut_m3, sigma)}</dd></div>
        <div><dt>Fill (below base)</dt><dd data-value={q.fill_m3}>{formatVolume(q.fill_m3, sigma)}</dd></div>
        <div><dt>Net</dt><dd data-value={net}><strong>{formatVolumePm(net, sigma)}</strong></dd></div>
      </dl>
      <p class="small muted">Measured by the server on this run's surface model, exactly as the volumes step measures a saved stockpile{baseZ !== null ? ` (base at ${baseZ.toFixed(2)} m)` : ""}; ± is 1σ.</p>
    </div>
  );
}
