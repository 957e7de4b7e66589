/** What the survey page hands to each of its tabs: the survey, its site, its runs and the one shown. A module
 * of its own so that the tab views do not import the page that imports them. */

import type { Run, Site, Survey } from "../api/types";

export interface SurveyContext {
  survey: Survey;
  site: Site;
  runs: Run[];
  /** The run the result tabs show. */
  run: Run | null;
  canEdit: boolean;
  reloadRuns: () => void;
  selectRun: (id: string) => void;
}
