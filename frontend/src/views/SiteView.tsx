/** A site: its surveys over time with their accuracy and volumes, and a new survey. */

import { useState } from "preact/hooks";
import { api, mapLimit } from "../api/client";
import { surveySummary, totalVolume } from "../api/summaries";
import type { Me, Page, Site, Stockpile, Survey, VolumePoint } from "../api/types";
import { LineChart, type Series } from "../components/LineChart";
import { ErrorBox, Field, Loading, StatePill } from "../components/ui";
import { useLoad } from "../hooks";
import { flightDate, formatVolume, formatVolumePm } from "../lib/format";
import { formatLength } from "../lib/residuals";
import { href, navigate } from "../router";
import { DesignPanel } from "./DesignPanel";
import { InventoryPanel } from "./InventoryPanel";
import { SiteCalibrationPanel } from "./SiteCalibrationPanel";

const PALETTE = ["#1f6feb", "#d9480f", "#2b8a3e", "#ae3ec9", "#e67700", "#0b7285", "#c2255c", "#5c940d"];

export function SiteView({ siteId, me }: { siteId: string; me: Me }) {
  const site = useLoad((signal) => api.get<Site>(`/sites/${siteId}`, { signal }), [siteId]);
  const surveys = useLoad((signal) => api.get<Page<Survey>>(`/sites/${siteId}/surveys`, { query: { limit: 100 }, signal }), [siteId]);
  const summaries = useLoad(
    async (signal) => (surveys.data ? mapLimit(surveys.data.items.slice(0, 40), 4, (s) => surveySummary(s, signal)) : []),
    [surveys.data],
  );
  const piles = useLoad((signal) => api.get<Stockpile[]>(`/sites/${siteId}/stockpiles`, { signal }), [siteId]);
  const history = useLoad(
    async (signal) =>
      piles.data ? mapLimit(piles.data, 4, async (p) => ({ pile: p, points: await api.get<VolumePoint[]>(`/stockpiles/${p.id}/volumes`, { signal }) })) : [],
    [piles.data],
  );
  const [creating, setCreating] = useState(false);
  const role = me.site_roles.find((r) => r.site_id === siteId)?.role;
  const canEdit = role === "editor" || role === "admin" || me.user.is_org_admin;

  if (site.error) return <ErrorBox error={site.error} title="This site could not be opened" />;
  if (!site.data) return <Loading what="the site" />;
  const s = site.data;
  const timeOf = (sv: Survey) => Date.parse(sv.flown_at ?? sv.created_at);

  const rmseSeries: Series[] = [];
  if (summaries.data?.some((x) => x.stats)) {
    const sorted = [...summaries.data].filter((x) => x.stats).sort((a, b) => timeOf(a.survey) - timeOf(b.survey));
    const pts = (f: (x: (typeof sorted)[number]) => number) => sorted.map((x) => ({ x: timeOf(x.survey), y: f(x) * 100, label: x.survey.name }));
    rmseSeries.push({ name: "horizontal", colour: PALETTE[0], points: pts((x) => x.stats!.horizontal.rmse), markers: true });
    rmseSeries.push({ name: "vertical", colour: PALETTE[1], points: pts((x) => x.stats!.dz.rmse), markers: true });
  }
  const volSeries: Series[] = (history.data ?? [])
    .filter((h) => h.points.some((p) => p.volume_m3 !== null))
    .map((h, i) => ({
      name: h.pile.name,
      colour: PALETTE[i % PALETTE.length],
      markers: true,
      points: h.points
        .filter((p) => p.measured_at || p.volume_m3 !== null)
        .map((p) => ({ x: Date.parse(p.measured_at ?? "") || 0, y: p.volume_m3, err: p.sigma_m3 ?? null, label: p.survey_name })),
    }));

  return (
    <section>
      <nav aria-label="Breadcrumb" class="crumbs"><a href={href()}>Sites</a> ›</nav>
      <div class="page-head">
        <h1>{s.name}</h1>
        {canEdit ? <button type="button" class="primary" onClick={() => setCreating(!creating)} aria-expanded={creating}>New survey</button> : null}
      </div>
      <p class="muted">{s.crs}{s.vertical_datum ? ` + ${s.vertical_datum}` : " · ellipsoidal heights"}{s.description ? ` · ${s.description}` : ""}</p>
      {creating ? <NewSurvey siteId={siteId} onDone={(sv) => navigate(href("surveys", sv.id, "upload"))} /> : null}

      <h2>Surveys</h2>
      <ErrorBox error={surveys.error} />
      {surveys.loading && !surveys.data ? <Loading what="surveys" /> : null}
      {surveys.data && !surveys.data.items.length ? <p class="empty">No survey yet{canEdit ? ": start with “New survey” and drop the flight's folder." : "."}</p> : null}
      {surveys.data && surveys.data.items.length ? (
        <div class="table-wrap">
          <table class="data">
            <caption class="sr-only">Surveys of {s.name}, newest first</caption>
            <thead>
              <tr>
                <th scope="col">Survey</th>
                <th scope="col">Flown</th>
                <th scope="col">State</th>
                <th scope="col" class="num">Check RMSE H (cm)</th>
                <th scope="col" class="num">Check RMSE V (cm)</th>
                <th scope="col" class="num">Stockpiles</th>
              </tr>
            </thead>
            <tbody>
              {surveys.data.items.map((sv) => {
                const sum = summaries.data?.find((x) => x.survey.id === sv.id);
                const v = totalVolume(sum?.volumes ?? null);
                return (
                  <tr key={sv.id}>
                    <th scope="row"><a href={href("surveys", sv.id)}>{sv.name}</a></th>
                    <td title={flightDate(sv).note || undefined}>{flightDate(sv).text}</td>
                    <td>{sum ? <StatePill state={sum.latestRun?.state ?? "none"} /> : "…"}</td>
                    <td class="num">{sum?.stats ? formatLength(sum.stats.horizontal.rmse, "cm") : "–"}</td>
                    <td class="num">{sum?.stats ? formatLength(sum.stats.dz.rmse, "cm") : "–"}</td>
                    <td class="num">{v === null ? "–" : formatVolume(v)}</td>
                  </tr>
                );
              })}
            </tbody>
          </table>
        </div>
      ) : null}

      <div class="two-col">
        <div>
          <h2>Accuracy over time</h2>
          {rmseSeries.length ? (
            <LineChart title="Check-point RMSE per survey" yLabel="cm" series={rmseSeries} xTime yZero />
          ) : (
            <p class="muted">Appears once surveys with check points are processed.</p>
          )}
        </div>
        <div>
          <h2>Stockpile volumes</h2>
          {volSeries.length ? (
            <LineChart title="Net volume per stockpile" yLabel="m³" series={volSeries} xTime yZero yFormat={(v) => Math.round(v).toLocaleString("en-GB")} />
          ) : (
            <p class="muted">{piles.data && piles.data.length ? "No volume measured yet." : "No stockpile outlined yet: draw one in a survey's Volumes view."}</p>
          )}
          {piles.data && piles.data.length ? (
            <ul class="plain">
              {piles.data.map((p) => {
                const h = history.data?.find((x) => x.pile.id === p.id)?.points ?? [];
                const last = [...h].reverse().find((x) => x.volume_m3 !== null);
                return (
                  <li key={p.id}>
                    <strong>{p.name}</strong> <span class="muted">base {p.base}{p.material ? ` · ${p.material_label || p.material}` : ""}</span>
                    {last ? <> — {formatVolumePm(last.volume_m3, last.sigma_m3)} <span class="muted">({last.survey_name})</span></> : null}
                  </li>
                );
              })}
            </ul>
          ) : null}
        </div>
      </div>

      <h2>Stockpile inventory</h2>
      <InventoryPanel siteId={siteId} piles={piles.data} />

      <h2>Design progress</h2>
      <DesignPanel siteId={siteId} canEdit={canEdit} />

      <h2>Site calibration</h2>
      <SiteCalibrationPanel siteId={siteId} canAdmin={role === "admin" || me.user.is_org_admin} />
    </section>
  );
}

function NewSurvey({ siteId, onDone }: { siteId: string; onDone: (s: Survey) => void }) {
  const today = new Date().toISOString().slice(0, 10);
  const [name, setName] = useState(`Flight ${today}`);
  const [date, setDate] = useState(today);
  const [error, setError] = useState<Error | null>(null);
  const [busy, setBusy] = useState(false);
  const submit = async (e: Event) => {
    e.preventDefault();
    setBusy(true);
    setError(null);
    try {
      onDone(await api.post<Survey>(`/sites/${siteId}/surveys`, { name: name.trim(), flown_at: date ? `${date}T12:00:00Z` : null }));
    } catch (err) {
      setError(err as Error);
    } finally {
      setBusy(false);
    }
  };
  return (
    <form class="card form-row" onSubmit={submit} aria-label="New survey">
      <Field id="survey-name" label="Survey name">
        <input id="survey-name" required value={name} onInput={(e) => setName((e.target as HTMLInputElement).value)} />
      </Field>
      <Field id="survey-date" label="Flight date">
        <input id="survey-date" type="date" value={date} onInput={(e) => setDate((e.target as HTMLInputElement).value)} />
      </Field>
      <button type="submit" class="primary" disabled={busy}>Create and upload data</button>
      <ErrorBox error={error} />
    </form>
  );
}
