/** A survey: its tabs (upload, processing, accuracy, map, volumes, downloads) around one chosen run. */

import { api } from "../api/client";
import type { Me, Page, Run, Site, Survey } from "../api/types";
import { ErrorBox, Loading, StatePill, Tabs } from "../components/ui";
import { useLoad } from "../hooks";
import { flightDate, formatDateTime } from "../lib/format";
import { href, navigate } from "../router";
import { AccuracyView } from "./AccuracyView";
import { DownloadsView } from "./DownloadsView";
import { MapTab } from "./MapTab";
import { ProcessingView } from "./ProcessingView";
import { UploadView } from "./UploadView";
import { VolumesView } from "./VolumesView";
import type { SurveyContext } from "./surveyContext";

export type { SurveyContext };

const TABS = [
  ["upload", "Data"],
  ["processing", "Processing"],
  ["accuracy", "Accuracy"],
  ["map", "Map"],
  ["volumes", "Volumes"],
  ["downloads", "Downloads"],
] as const;

export function SurveyView({ surveyId, tab, query, me }: { surveyId: string; tab: string; query: URLSearchParams; me: Me }) {
  const survey = useLoad((signal) => api.get<Survey>(`/surveys/${surveyId}`, { signal }), [surveyId]);
  const site = useLoad(
    async (signal) => (survey.data ? api.get<Site>(`/sites/${survey.data.site_id}`, { signal }) : undefined),
    [survey.data?.site_id],
  );
  const runs = useLoad((signal) => api.get<Page<Run>>(`/surveys/${surveyId}/runs`, { query: { limit: 100 }, signal }), [surveyId]);

  if (survey.error) return <ErrorBox error={survey.error} title="This survey could not be opened" />;
  if (!survey.data || !site.data || !runs.data) return <Loading what="the survey" />;

  const runList = runs.data.items;
  const wanted = query.get("run");
  const lastGood = runList.find((r) => r.state === "succeeded") ?? null;
  const run = (wanted ? runList.find((r) => r.id === wanted) : null) ?? lastGood ?? runList[0] ?? null;
  let current = tab;
  if (!TABS.some(([id]) => id === current)) {
    current = !runList.length ? "upload" : runList[0].state === "running" || runList[0].state === "queued" || !lastGood ? "processing" : "accuracy";
  }
  const role = me.site_roles.find((r) => r.site_id === site.data!.id)?.role;
  const ctx: SurveyContext = {
    survey: survey.data,
    site: site.data,
    runs: runList,
    run,
    canEdit: role === "editor" || role === "admin" || me.user.is_org_admin,
    reloadRuns: runs.reload,
    selectRun: (id) => navigate(`${href("surveys", surveyId, current)}?run=${encodeURIComponent(id)}`),
  };
  const runQuery = wanted ? `?run=${encodeURIComponent(wanted)}` : "";
  const resultTab = current !== "upload" && current !== "processing";

  return (
    <section>
      <nav aria-label="Breadcrumb" class="crumbs">
        <a href={href()}>Sites</a> › <a href={href("sites", site.data.id)}>{site.data.name}</a> ›
      </nav>
      <div class="page-head">
        <h1>{survey.data.name}</h1>
        <FlightDate survey={survey.data} />
      </div>
      <Tabs label="Survey views" current={current} tabs={TABS.map(([id, label]) => ({ id, label, href: href("surveys", surveyId, id) + runQuery }))} />
      {resultTab && runList.length > 1 ? (
        <div class="run-picker">
          <label for="run-select">Results of</label>
          <select id="run-select" value={run?.id ?? ""} onChange={(e) => ctx.selectRun((e.target as HTMLSelectElement).value)}>
            {runList.map((r) => (
              <option key={r.id} value={r.id}>
                run {r.number} · {r.state} · {formatDateTime(r.finished_at ?? r.created_at)}
              </option>
            ))}
          </select>
          {run ? <StatePill state={run.state} /> : null}
        </div>
      ) : null}
      {resultTab && !run ? <p class="empty">Nothing processed yet: upload the survey data and start processing in the <a href={href("surveys", surveyId, "processing")}>Processing</a> tab.</p> : null}
      <div class="tab-body">
        {current === "upload" ? <UploadView ctx={ctx} /> : null}
        {current === "processing" ? <ProcessingView ctx={ctx} runId={wanted} /> : null}
        {current === "accuracy" && run ? <AccuracyView ctx={ctx} run={run} /> : null}
        {current === "map" && run ? <MapTab ctx={ctx} run={run} /> : null}
        {current === "volumes" && run ? <VolumesView ctx={ctx} run={run} /> : null}
        {current === "downloads" && run ? <DownloadsView ctx={ctx} run={run} /> : null}
      </div>
    </section>
  );
}

/** "flown 2024-06-24 (from the GNSS data)": the date given or read from the data, never the upload date. */
export function FlightDate({ survey }: { survey: Survey }) {
  const d = flightDate(survey);
  return (
    <span class="muted" data-testid="flight-date" title={d.note || undefined}>
      {d.known ? `flown ${d.text}` : "flight date not known yet"}{d.note && d.known ? ` (${d.note})` : ""}
    </span>
  );
}
