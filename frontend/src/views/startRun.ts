/** Starting a processing run of a survey and opening its processing view: one action shared by the
 * processing tab and the upload page. */
import { useState } from "preact/hooks";
import { api } from "../api/client";
import type { RunDetail } from "../api/types";
import { href, navigate } from "../router";
import type { SurveyContext } from "./SurveyView";

export function useStartRun(ctx: SurveyContext): { start: () => Promise<void>; busy: boolean; error: Error | null } {
  const [busy, setBusy] = useState(false);
  const [error, setError] = useState<Error | null>(null);
  const start = async () => {
    setBusy(true);
    setError(null);
    try {
      const run = await api.post<RunDetail>(`/surveys/${ctx.survey.id}/runs`, {});
      ctx.reloadRuns();
      navigate(`${href("surveys", ctx.survey.id, "processing")}?run=${run.id}`);
    } catch (e) {
      setError(e as Error);
    } finally {
      setBusy(false);
    }
  };
  return { start, busy, error };
}
