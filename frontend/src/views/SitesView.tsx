/** The first page: every site with its latest survey, its state and key figures. */

import { useState } from "preact/hooks";
import { api } from "../api/client";
import { type SiteSummary, siteSummaries, totalVolume } from "../api/summaries";
import type { Me, Page, Site } from "../api/types";
import { ErrorBox, Field, Loading, StatePill } from "../components/ui";
import { useLoad } from "../hooks";
import { flightDate, formatVolume } from "../lib/format";
import { formatLength } from "../lib/residuals";
import { href, navigate } from "../router";

export function SitesView({ me }: { me: Me }) {
  const sites = useLoad((signal) => api.get<Page<Site>>("/sites", { query: { limit: 200 }, signal }), []);
  const summaries = useLoad(
    async (signal) => (sites.data ? siteSummaries(sites.data.items, signal) : []),
    [sites.data],
  );
  const [creating, setCreating] = useState(false);

  return (
    <section>
      <div class="page-head">
        <h1>Sites</h1>
        <button type="button" class="secondary" onClick={() => setCreating(!creating)} aria-expanded={creating}>New site</button>
      </div>
      {creating ? <NewSite onDone={(s) => navigate(href("sites", s.id))} /> : null}
      <ErrorBox error={sites.error} title="Sites could not be loaded" />
      {sites.loading && !sites.data ? <Loading what="sites" /> : null}
      {sites.data && sites.data.items.length === 0 ? (
        <p class="empty">No site yet. {me.site_roles.length === 0 ? "Create one with “New site”, or ask an administrator to give you access." : ""}</p>
      ) : null}
      <ul class="site-grid">
        {(sites.data?.items ?? []).map((s) => {
          const sum = summaries.data?.find((x) => x.site.id === s.id);
          return <SiteCard key={s.id} site={s} summary={sum} loading={summaries.loading} />;
        })}
      </ul>
    </section>
  );
}

function SiteCard({ site, summary, loading }: { site: Site; summary?: SiteSummary; loading: boolean }) {
  const latest = summary?.latest;
  const run = latest?.latestRun;
  const vol = totalVolume(latest?.volumes ?? null);
  return (
    <li class="card site-card">
      <h2><a href={href("sites", site.id)}>{site.name}</a></h2>
      <p class="muted small">{site.crs}{site.description ? ` · ${site.description}` : ""}</p>
      {!summary ? (
        loading ? <p class="muted small">Loading figures…</p> : null
      ) : !latest ? (
        <p class="muted">No survey yet.</p>
      ) : (
        <>
          <p>
            Latest survey: <a href={href("surveys", latest.survey.id)}>{latest.survey.name}</a>{" "}
            <span class="muted">(flown {flightDate(latest.survey).text})</span>{" "}
            <StatePill state={run?.state ?? "none"} />
          </p>
          <dl class="figures-inline">
            <div>
              <dt>Check RMSE (3D)</dt>
              <dd>{latest.stats ? `${formatLength(latest.stats.d3.rmse, "cm")} cm` : "–"}</dd>
            </div>
            <div>
              <dt>Check points</dt>
              <dd>{latest.stats ? latest.checkPoints : "–"}</dd>
            </div>
            <div>
              <dt>Stockpiles</dt>
              <dd>{vol === null ? "–" : formatVolume(vol)}</dd>
            </div>
            <div>
              <dt>Surveys</dt>
              <dd>{summary.surveys}</dd>
            </div>
          </dl>
        </>
      )}
    </li>
  );
}

function NewSite({ onDone }: { onDone: (s: Site) => void }) {
  const [name, setName] = useState("");
  const [crs, setCrs] = useState("EPSG:");
  const [error, setError] = useState<Error | null>(null);
  const [busy, setBusy] = useState(false);
  const submit = async (e: Event) => {
    e.preventDefault();
    setBusy(true);
    setError(null);
    try {
      onDone(await api.post<Site>("/sites", { name: name.trim(), crs: crs.trim() }));
    } catch (err) {
      setError(err as Error);
    } finally {
      setBusy(false);
    }
  };
  return (
    <form class="card form-row" onSubmit={submit} aria-label="New site">
      <Field id="site-name" label="Site name">
        <input id="site-name" required value={name} onInput={(e) => setName((e.target as HTMLInputElement).value)} />
      </Field>
      <Field id="site-crs" label="Coordinate system" hint="The projected CRS of the site plans, e.g. EPSG:32631 (UTM 31N).">
        <input id="site-crs" required pattern="EPSG:\d{4,6}" value={crs} aria-describedby="site-crs-hint" onInput={(e) => setCrs((e.target as HTMLInputElement).value)} />
      </Field>
      <button type="submit" class="primary" disabled={busy}>Create site</button>
      <ErrorBox error={error} />
    </form>
  );
}
