/** The site's design surface and the surveys' progress against it: the file, area and tolerance
 * (GET /sites/{id}/design; an editor uploads a file with PUT .../design/file and sets the area and tolerance
 * with PATCH and If-Match), and per survey cut, fill, net ± 1σ and the on-grade share
 * (GET /sites/{id}/design-progress) as a table and a chart of net ± 1σ over time. */

import { useEffect, useState } from "preact/hooks";
import { api, ApiError } from "../api/client";
import { LineChart } from "../components/LineChart";
import { ErrorBox, Field, Loading, Note } from "../components/ui";
import { useLoad } from "../hooks";
import {
  areaFromExtent,
  areaFromGeoJson,
  changeState,
  DESIGN_FILE_ACCEPT,
  formatChange,
  formatShare,
  netSeriesPoints,
  parseToleranceCm,
  progressPollDelayMs,
  type DesignProgress,
  type SiteDesign,
} from "../lib/designProgress";
import { formatArea, formatBytes, formatDate, formatDateTime, formatVolumeNumber } from "../lib/format";
import { formatPm } from "../lib/inventory";
import { href } from "../router";

/** The design (null: the site has none yet) with its ETag. */
async function loadDesign(siteId: string, signal: AbortSignal): Promise<{ design: SiteDesign | null; etag: string | null }> {
  try {
    const r = await api.getWithEtag<SiteDesign>(`/sites/${siteId}/design`, { signal });
    return { design: r.data, etag: r.etag };
  } catch (e) {
    if (e instanceof ApiError && e.status === 404) return { design: null, etag: null };
    throw e;
  }
}

export function DesignPanel({ siteId, canEdit }: { siteId: string; canEdit: boolean }) {
  const design = useLoad((signal) => loadDesign(siteId, signal), [siteId]);
  const hasDesign = !!design.data?.design;
  const progress = useLoad(
    async (signal) => (hasDesign ? api.maybe<DesignProgress>(`/sites/${siteId}/design-progress`, { signal }) : null),
    [siteId, hasDesign, design.data?.design?.key],
  );
  const reload = () => {
    design.reload();
    progress.reload();
  };
  // a change between surveys being computed by a worker (202): ask again later, never waiting on a request
  const [polls, setPolls] = useState(0);
  useEffect(() => {
    if (progress.loading) return;
    const ms = progressPollDelayMs(progress.data, polls);
    if (ms === null) {
      if (polls && !progress.data?.changes_pending) setPolls(0);
      return;
    }
    const id = setTimeout(() => {
      setPolls((n) => n + 1);
      progress.reload();
    }, ms);
    return () => clearTimeout(id);
    // eslint-disable-next-line react-hooks/exhaustive-deps
  }, [progress.data, progress.loading, polls]);
  if (design.error) return <ErrorBox error={design.error} title="The design could not be read" />;
  if (!design.data) return <Loading what="the design" />;
  const d = design.data.design;
  return (
    <div class="design-panel" data-testid="design-panel">
      {d ? <DesignSummary d={d} /> : <p class="muted">No design surface yet{canEdit ? ": upload the design (LandXML, DXF or GeoTIFF) to compare every survey with it." : "."}</p>}
      {canEdit ? <DesignEditor siteId={siteId} design={d} etag={design.data.etag} onChanged={reload} /> : null}
      {d ? <ProgressView p={progress.data ?? null} error={progress.error} loading={progress.loading} /> : null}
    </div>
  );
}

function DesignSummary({ d }: { d: SiteDesign }) {
  const x = d.described ?? {};
  const hr = x.height_range_m;
  return (
    <div class="card design-summary">
      <p>
        <strong>{d.filename}</strong> <span class="muted">({d.format}{d.surface_name ? `, surface “${d.surface_name}”` : ""}, {formatBytes(d.size)})</span>{" "}
        <a class="small" href={`/api/v1/sites/${encodeURIComponent(d.site_id)}/design/file`} download={d.filename}>download</a>
      </p>
      <p class="small muted">
        {x.n_triangles ? `${x.n_triangles.toLocaleString("en-GB")} triangles · ` : ""}
        {x.n_points ? `${x.n_points.toLocaleString("en-GB")} points · ` : ""}
        {hr && hr.length === 2 ? `heights ${hr[0].toFixed(2)} to ${hr[1].toFixed(2)} m · ` : ""}
        uploaded {formatDateTime(d.updated_at)}
      </p>
      <p>
        Area compared: {d.area ? <strong>{formatArea(d.area_m2)}</strong> : <span class="warn-text">not set: surveys are compared with the design only once an area is set</span>}
        {" · "}on grade within <strong>± {(d.tolerance_m * 100).toFixed(1)} cm</strong>
      </p>
      {x.notes && x.notes.length ? <ul class="small muted">{x.notes.map((n) => <li key={n}>{n}</li>)}</ul> : null}
    </div>
  );
}

function DesignEditor({ siteId, design, etag, onChanged }: { siteId: string; design: SiteDesign | null; etag: string | null; onChanged: () => void }) {
  const [busy, setBusy] = useState<string | null>(null);
  const [error, setError] = useState<Error | null>(null);
  const [done, setDone] = useState<string | null>(null);
  const [tol, setTol] = useState(design ? String(+(design.tolerance_m * 100).toFixed(1)) : "5");
  const [surface, setSurface] = useState("");

  const act = async (what: string, f: () => Promise<unknown>, message: string) => {
    setBusy(what);
    setError(null);
    setDone(null);
    try {
      await f();
      setDone(message);
      onChanged();
    } catch (e) {
      setError(e as Error);
      if (e instanceof ApiError && e.status === 412) onChanged(); // changed meanwhile: read it (and its ETag) again
    } finally {
      setBusy(null);
    }
  };
  const ifMatch = etag ? { "If-Match": etag } : undefined;

  const upload = (file: File) =>
    act("upload", () => api.put<SiteDesign>(`/sites/${siteId}/design/file`, {
      body: file,
      headers: { "Content-Type": "application/octet-stream" },
      query: { filename: file.name, surface_name: surface.trim() || null },
    }), `${file.name} read and stored${design?.area ? "" : ": now set the area to compare"}.`);

  const saveTolerance = (e: Event) => {
    e.preventDefault();
    const t = parseToleranceCm(tol);
    if ("error" in t) {
      setError(new Error(t.error));
      return;
    }
    void act("tolerance", () => api.patch(`/sites/${siteId}/design`, { tolerance_m: t.value_m }, { headers: ifMatch }), `Tolerance set to ± ${(t.value_m * 100).toFixed(1)} cm: the next runs compare with it.`);
  };

  const setArea = (area: unknown, what: string) =>
    act("area", () => api.patch(`/sites/${siteId}/design`, { area }, { headers: ifMatch }), `Area set (${what}): the next runs compare with the design.`);

  const importArea = async (file: File) => {
    try {
      const a = areaFromGeoJson(await file.text(), design?.described?.extent);
      await setArea(a.area, `${file.name}${a.parts > 1 ? `, ${a.parts} parts` : ""}`);
    } catch (e) {
      setError(new Error(`${file.name}: ${(e as Error).message}`));
    }
  };
  const extentArea = areaFromExtent(design?.described?.extent);

  return (
    <div class="card design-editor">
      <div class="actions">
        <label class={`button ${design ? "secondary" : "primary"} small`}>
          {busy === "upload" ? "Uploading…" : design ? "Replace the design file…" : "Upload a design file…"}
          <input type="file" accept={DESIGN_FILE_ACCEPT} class="visually-hidden-input" disabled={!!busy} aria-label="Design file (LandXML, DXF or GeoTIFF)"
            onChange={(e) => { const f = (e.target as HTMLInputElement).files?.[0]; if (f) void upload(f); (e.target as HTMLInputElement).value = ""; }} />
        </label>
        <label class="small">LandXML surface <input class="narrow" value={surface} placeholder="the first" onInput={(e) => setSurface((e.target as HTMLInputElement).value)} /></label>
      </div>
      {design ? (
        <>
          <form class="form-row" onSubmit={saveTolerance} aria-label="Design tolerance">
            <Field id="design-tolerance" label="On-grade tolerance (± cm)">
              <input id="design-tolerance" inputMode="decimal" class="narrow" value={tol} onInput={(e) => setTol((e.target as HTMLInputElement).value)} />
            </Field>
            <button type="submit" class="secondary small" disabled={!!busy}>Set tolerance</button>
          </form>
          <div class="actions">
            <label class="button secondary small">Area from GeoJSON…
              <input type="file" accept=".geojson,.json,application/geo+json,application/json" class="visually-hidden-input" disabled={!!busy} aria-label="Design area (GeoJSON in the site CRS)"
                onChange={(e) => { const f = (e.target as HTMLInputElement).files?.[0]; if (f) void importArea(f); (e.target as HTMLInputElement).value = ""; }} />
            </label>
            {extentArea ? <button type="button" class="secondary small" disabled={!!busy} onClick={() => setArea(extentArea, "the design's extent")}>Use the design's extent as the area</button> : null}
          </div>
        </>
      ) : null}
      <ErrorBox error={error} title={error instanceof ApiError && error.status === 422 ? "Not accepted" : undefined} />
      {done ? <Note kind="ok">{done}</Note> : null}
    </div>
  );
}

function ProgressView({ p, error, loading }: { p: DesignProgress | null; error: Error | null; loading: boolean }) {
  if (error) return <ErrorBox error={error} title="The progress could not be read" />;
  if (!p) return loading ? <Loading what="the progress" /> : null;
  const pts = netSeriesPoints(p);
  return (
    <div class="design-progress">
      {p.surveys.length ? (
        <>
          <div class="table-wrap">
            <table class="data compact">
              <caption class="sr-only">Cut, fill and net to the design per survey; uncertainties 1 sigma</caption>
              <thead>
                <tr>
                  <th scope="col">Survey</th>
                  <th scope="col">Flown</th>
                  <th scope="col" class="num">Cut (m³)</th>
                  <th scope="col" class="num">Fill (m³)</th>
                  <th scope="col" class="num">Net cut − fill (m³)</th>
                  <th scope="col" class="num">On grade (share of area)</th>
                </tr>
              </thead>
              <tbody>
                {p.surveys.map((e) => {
                  const net = formatPm(e.net_m3, e.sigma_m3?.net_m3, { signed: true });
                  return (
                    <tr key={e.survey_id}>
                      <th scope="row"><a href={`${href("surveys", e.survey_id, "map")}?run=${encodeURIComponent(e.run_id)}`}>{e.survey_name}</a></th>
                      <td>{formatDate(e.flown_at)}</td>
                      <td class="num" title={e.sigma_m3?.cut_m3 ? `± ${formatVolumeNumber(e.sigma_m3.cut_m3)} (1σ)` : undefined}>{formatVolumeNumber(e.cut_m3, e.sigma_m3?.cut_m3)}</td>
                      <td class="num" title={e.sigma_m3?.fill_m3 ? `± ${formatVolumeNumber(e.sigma_m3.fill_m3)} (1σ)` : undefined}>{formatVolumeNumber(e.fill_m3, e.sigma_m3?.fill_m3)}</td>
                      <td class="num">{net.value}{net.pm ? <span class="pm"> {net.pm}</span> : null}</td>
                      <td class="num" title={e.tolerance_m ? `within ± ${(e.tolerance_m * 100).toFixed(1)} cm` : undefined}>
                        {formatShare(e.on_grade_share)}
                        {e.warnings.length ? <span class="block small warn-text">{e.warnings.join("; ")}</span> : null}
                      </td>
                    </tr>
                  );
                })}
              </tbody>
            </table>
          </div>
          <ChangeTable p={p} />
          {pts.length ? (
            <LineChart title="Net to design (cut − fill) per survey, ± 1σ" yLabel="m³" xTime yZero height={200} series={[{ name: "net", colour: "#1f6feb", markers: true, points: pts }]}
              valueFormat={(v) => formatVolumeNumber(v)} />
          ) : null}
        </>
      ) : (
        <p class="muted">No survey compared with this design yet: runs after the area is set compare with it.</p>
      )}
      {p.not_compared.length ? (
        <details class="small">
          <summary>{p.not_compared.length} survey{p.not_compared.length > 1 ? "s" : ""} not compared with this design</summary>
          <ul>{p.not_compared.map((n) => <li key={n.survey_id}>{n.survey_name}: {n.reason}</li>)}</ul>
        </details>
      ) : null}
    </div>
  );
}

/** Per survey after the first: what moved toward the design since the survey before it (± 1σ, the design's own
 * error cancelling) and what remains to the design (design-progress `since_previous`). */
function ChangeTable({ p }: { p: DesignProgress }) {
  const rows = p.surveys.filter((e) => e.since_previous);
  if (!rows.length) return p.surveys.length === 1 ? <p class="small muted">The change since the previous survey appears from the second compared survey on.</p> : null;
  return (
    <div class="table-wrap">
      <table class="data compact" data-testid="design-change">
        <caption>Since the previous survey (m³, ± 1σ; surface against surface inside the design area) and what remains to the design
          {p.changes_pending ? <span class="block small muted" role="status">A change is being computed by a worker: this table updates by itself.</span> : null}</caption>
        <thead>
          <tr>
            <th scope="col">Survey</th>
            <th scope="col">Since</th>
            <th scope="col" class="num">Cut removed</th>
            <th scope="col" class="num">Fill placed</th>
            <th scope="col" class="num">Net change</th>
            <th scope="col" class="num">Cut remaining</th>
            <th scope="col" class="num">Fill remaining</th>
            <th scope="col" class="num">Done since first (cut / fill)</th>
            <th scope="col">Comparison</th>
          </tr>
        </thead>
        <tbody>
          {rows.map((e) => {
            const c = e.since_previous!;
            const st = changeState(c);
            return (
              <tr key={e.survey_id}>
                <th scope="row">{e.survey_name}</th>
                <td>{c.previous_survey_name}{c.days !== null ? <span class="small muted"> ({Math.round(c.days)} d)</span> : null}
                  {c.notes.length ? <span class="block small warn-text">{c.notes.join("; ")}</span> : null}</td>
                <td class="num" title={c.cut_below_design_m3 ? `of which below the design (over-excavation): ${formatVolumeNumber(c.cut_below_design_m3)}` : undefined}>{formatChange(c.cut_moved_m3, c.sigma_m3.cut_moved_m3)}</td>
                <td class="num" title={c.fill_above_design_m3 ? `of which above the design: ${formatVolumeNumber(c.fill_above_design_m3)}` : undefined}>{formatChange(c.fill_placed_m3, c.sigma_m3.fill_placed_m3)}</td>
                <td class="num">{formatChange(c.net_change_m3, c.sigma_m3.net_change_m3)}</td>
                <td class="num">{formatVolumeNumber(c.remaining_cut_m3)}</td>
                <td class="num">{formatVolumeNumber(c.remaining_fill_m3)}</td>
                <td class="num">{formatShare(c.done_share.cut_m3)} / {formatShare(c.done_share.fill_m3)}</td>
                <td class={`small ${st.pending ? "muted" : ""}`} data-testid="change-state" data-state={c.surfaces_state ?? "none"}>{st.label}</td>
              </tr>
            );
          })}
        </tbody>
      </table>
    </div>
  );
}
