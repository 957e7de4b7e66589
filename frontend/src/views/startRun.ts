/** Starting a processing run of a survey and opening its processing view: one action shared by the
 * processing tab and the upload page; showRun opens any new run (re-runs included). */
import { useState } from "preact/hooks";
import { api } from "../api/client";
import type { RunDetail } from "../api/types";
import { href, navigate } from "../router";
import type { SurveyContext } from "./surveyContext";

/** The address of a run's processing view. */
export function runHref(ctx: SurveyContext, runId: string): string {
  return `${href("surveys", ctx.survey.id, "processing")}?run=${runId}`;
}

/** After a run was started or re-run: refresh the survey's runs and show the run's processing view. */
export function showRun(ctx: SurveyContext, runId: string): void {
  ctx.reloadRuns();
  navigate(runHref(ctx, runId));
}

export function useStartRun(ctx: SurveyContext): { start: () => Promise<void>; busy: boolean; error: Error | null } {
  const [busy, setBusy] = useState(false);
  const [error, setError] = useState<Error | null>(null);
  const start = async () => {
    setBusy(true);
    setError(null);
    try {
      const run = await api.post<RunDetail>(`/surveys/${ctx.survey.id}/runs`, {});
      showRun(ctx, run.id);
    } catch (e) {
      setError(e as Error);
    } finally {
      setBusy(false);
    }
  };
  return { start, busy, error };
}
