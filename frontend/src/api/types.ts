/** Shapes of the REST API's JSON (backend/schemas). Only the fields the UI reads are typed strictly. */

export interface Page<T> {
  items: T[];
  total: number;
  limit: number;
  offset: number;
}

export interface User {
  id: string;
  email: string;
  name: string;
  organisation_id: string;
  is_org_admin: boolean;
}

export interface SiteRole {
  site_id: string;
  site_name: string;
  role: "viewer" | "editor" | "admin";
}

export interface Me {
  user: User;
  organisation: { id: string; name: string };
  auth: string;
  scopes: string[];
  csrf_token: string | null;
  site_roles: SiteRole[];
}

export interface LoginResult {
  user: User;
  csrf_token: string;
  expires_at: string;
}

export interface Site {
  id: string;
  organisation_id: string;
  name: string;
  crs: string;
  vertical_datum: string | null;
  geoid: string | null;
  description: string;
  tolerance_horizontal_m?: number | null;
  tolerance_vertical_m?: number | null;
  created_at: string;
  updated_at: string;
  version: number;
}

export interface Survey {
  id: string;
  site_id: string;
  name: string;
  flown_at: string | null;
  /** "user" (given), or read from the data by a run: "gnss", "dji-mrk", "exif"; null without a date */
  flown_at_source?: string | null;
  notes: string;
  settings: Record<string, Record<string, unknown>>;
  created_at: string;
  updated_at: string;
  version: number;
}

export interface SurveyFile {
  id: string;
  path: string;
  kind: string;
  role: string | null;
  size: number;
  sha256: string;
  meta: Record<string, unknown> | null;
  created_at: string;
}

export interface Upload {
  id: string;
  survey_id: string;
  filename: string;
  size: number;
  sha256: string;
  kind: string | null;
  role: string | null;
  folder?: string | null;
  state: "open" | "verifying" | "complete" | "failed" | "aborted" | string;
  received_bytes: number;
  error: string | null;
  result: Record<string, unknown> | null;
  created_at: string;
  expires_at: string | null;
  max_chunk_bytes: number;
}

export interface CheckProblem {
  severity: "error" | "warning" | "info";
  code: string;
  message: string;
  files: string[];
}

export interface Check {
  survey_id: string;
  ok: boolean;
  errors: number;
  warnings: number;
  problems: CheckProblem[];
  files: Record<string, number>;
  /** What was found, in one line ("2 flights, 419 photos, MRK 419 exposures, ..."). */
  summary?: string;
}

export type RunState = "queued" | "running" | "succeeded" | "failed" | "cancelled";
export type StepState = "pending" | "queued" | "running" | "succeeded" | "skipped" | "failed" | "cancelled" | "unavailable";

export interface Step {
  name: string;
  position: number;
  state: StepState;
  attempt: number;
  worker: string | null;
  force: boolean;
  input_hash: string | null;
  reused_from_step_id: string | null;
  queued_at: string | null;
  started_at: string | null;
  finished_at: string | null;
  heartbeat_at: string | null;
  progress_stage: string;
  progress_done: number;
  progress_total: number;
  summary: Record<string, any> | null;
  error: string | null;
}

export interface Run {
  id: string;
  survey_id: string;
  site_id: string;
  number: number;
  state: RunState;
  trigger: string;
  parent_run_id: string | null;
  previous_run_id: string | null;
  from_step: string | null;
  steps: string[];
  settings: Record<string, Record<string, unknown>>;
  settings_hash: string;
  inputs: Record<string, string>;
  cancel_requested: boolean;
  error: string | null;
  created_at: string;
  started_at: string | null;
  finished_at: string | null;
}

export interface RunDetail extends Run {
  step_details: Step[];
  changes: Record<string, any> | null;
}

export interface LogLine {
  id: number;
  step_name: string | null;
  created_at: string;
  level: string;
  message: string;
}

export interface OutputFile {
  path: string;
  step_name: string;
  sha256: string;
  size: number;
  media_type: string;
  url: string;
}

export interface ApiPoint {
  name: string;
  easting_m: number;
  northing_m: number;
  ellipsoidal_height_m: number;
  role: "control" | "check" | string;
}

export interface ResidualRow {
  name: string;
  role: string;
  dx_m: number;
  dy_m: number;
  dz_m: number;
  d_m?: number;
  d3_m?: number;
  n_images?: number;
  note?: string;
  [k: string]: unknown;
}

export interface ResidualsResponse {
  run_id: string;
  units: string;
  points: ResidualRow[];
  stats: import("../lib/residuals").ServedStats;
  source: any;
}

export interface LeverArm {
  lever_arm_cam_m: [number, number, number];
  lever_arm_sigma_m: [number, number, number] | null;
  delay_s: number;
  delay_sigma_s: number | null;
  estimated?: { lever_arm: boolean; delay: boolean; readout?: boolean };
  model?: string;
  /** rolling-shutter readout (s), where the adjustment modelled it */
  readout_s?: number;
  readout_sigma_s?: number | null;
  correlations?: Record<string, number> | null;
}

export interface TrajectoryEpoch {
  gps_time_s: number;
  lat_deg: number;
  lon_deg: number;
  height_m: number;
  q: number;
  ns: number;
  sdn_m: number | null;
  sde_m: number | null;
  sdu_m: number | null;
  ratio: number | null;
}

/** The volume of an outline on a run's DSM, nothing saved (POST /runs/{id}/volumes): the volumes step's
 * computation, so it is the figure a saved stockpile gets. */
export interface OutlineVolume {
  run_id: string;
  /** the base surface as the volume computation describes it (method, elevation_m or z_ref_m, fit) */
  base: string | Record<string, any>;
  volume_m3: number;
  net_m3: number;
  cut_m3: number;
  fill_m3: number;
  area_m2: number;
  uncertainty?: { sigma_m3?: number; ci95_m3?: number } | null;
  warnings?: string[];
  [k: string]: unknown;
}

export interface TrajectoryResponse {
  run_id: string;
  count: number;
  epochs: TrajectoryEpoch[];
}

export interface Stockpile {
  id: string;
  site_id: string;
  name: string;
  outline: { type: "Polygon"; coordinates: number[][][] };
  base: string;
  material: string;
  /** the material as people read it ("crushed_stone" -> "Crushed stone"), from the server */
  material_label?: string;
  density_t_m3: number | null;
  created_at: string;
  updated_at: string;
  version: number;
}

export interface VolumePoint {
  run_id: string;
  run_number: number;
  run_state: string;
  survey_id: string;
  survey_name: string;
  measured_at: string | null;
  base: string;
  volume_m3: number | null;
  fill_m3: number | null;
  cut_m3: number | null;
  area_m2: number | null;
  tonnes: number | null;
  sigma_m3?: number | null;
}

export interface RunVolume {
  stockpile_id: string;
  name: string;
  base: string;
  volume_m3: number | null;
  fill_m3: number | null;
  cut_m3: number | null;
  area_m2: number | null;
  measured_at: string | null;
  sigma_m3?: number | null;
}

export interface Schedule {
  id: string;
  site_id: string;
  name: string;
  cadence: string;
  at_utc: string;
  weekday: number;
  on_new_base: boolean;
  on_new_points: boolean;
  scope: string;
  only_if_changed: boolean;
  steps: string[] | null;
  settings: Record<string, unknown>;
  enabled: boolean;
  next_run_at: string | null;
  last_run_at: string | null;
  pending_survey_ids: string[];
  version: number;
}
