"""`georef steps` and `georef step`: the pipeline steps as their specs declare them (georef_core.steps.contract),
and any step run on a survey folder through its spec, with the same option checks as the API:

    georef steps                            # every step: options with defaults, outputs
    georef steps --json                     # the specs as the API serves them (GET /api/v1/steps)
    georef step georef SURVEY --out OUT --set camera_model=radial --set gcp_sigma_m=[0.01,0.02]
    georef step volumes SURVEY --out OUT --settings settings.json --stockpiles piles.geojson

Values given with --set are JSON where they parse as JSON (numbers, true/false, lists), else text."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..errors import InputFileError


def register(sub) -> None:
    p = sub.add_parser("steps", help="list the pipeline steps, their options and outputs (the step contract)")
    p.add_argument("--json", action="store_true", help="print the specs as JSON (options as JSON Schema)")
    p.set_defaults(func=cmd_steps)
    r = sub.add_parser("step", help="run one pipeline step on a survey folder through its spec",
                       description="Runs a step as the platform's worker does: options checked against the "
                                   "step's spec, outputs written where the spec declares them.")
    r.add_argument("name", help="step name (see `georef steps`)")
    r.add_argument("survey", help="survey folder (rover/, base/, nav/, images/, gcp/, flights/, survey.json)")
    r.add_argument("--out", required=True, help="run folder: earlier steps' outputs are read from it")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="an option (repeatable)")
    r.add_argument("--settings", help="a JSON file of options for this step ({option: value}) or of sections "
                                      "({step: {option: value}})")
    r.add_argument("--crs", help="the site's CRS (e.g. EPSG:32631), for the steps that read it")
    r.add_argument("--vertical-datum", help="the site's vertical datum (e.g. EPSG:5773 EGM96 height), for the "
                                            "steps that read it (datum)")
    r.add_argument("--stockpiles", help="GeoJSON of stockpile outlines (properties name, base) in the site CRS, "
                                        "for the volumes step")
    r.add_argument("--json", action="store_true", help="print the summary as JSON")
    r.set_defaults(func=cmd_step)


def cmd_steps(args) -> int:
    from ..steps.contract import all_specs

    specs = all_specs()
    if args.json:
        print(json.dumps({"items": [s.as_dict() for s in specs]}, indent=1))
        return 0
    for s in specs:
        after = f" (after {', '.join(s.depends_on)})" if s.depends_on else ""
        print(f"{s.name} v{s.version}: {s.title}{after}")
        for o in s.options:
            default = "" if o.default is None else f" = {json.dumps(o.default) if not isinstance(o.default, tuple) else list(o.default)}"
            choice = f" ({' | '.join(o.choices)})" if o.choices else ""
            unit = f" [{o.unit}]" if o.unit else ""
            print(f"    --set {o.name}{default}{choice}{unit}  {o.help}")
        for o in s.outputs:
            print(f"    -> {o.path}  {o.description}")
    return 0


def _value(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return text


def cmd_step(args) -> int:
    from ..progress import no_progress
    from ..steps.contract import Workspace, get_spec

    spec = get_spec(args.name)
    options: dict = {}
    if args.settings:
        path = Path(args.settings)
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise InputFileError(path, f"not a JSON object of options ({exc})") from None
        if not isinstance(doc, dict):
            raise InputFileError(path, "not a JSON object of options")
        options.update(doc.get(spec.name, {}) if isinstance(doc.get(spec.name), dict) else doc)
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            raise InputFileError(None, f"--set {item!r}: expected KEY=VALUE")
        options[key.strip()] = _value(value.strip())
    options = spec.validate(options)
    context = {"crs": args.crs, "vertical_datum": args.vertical_datum,
               "stockpiles": _stockpiles(args.stockpiles) if args.stockpiles else []}
    if spec.function is None:
        raise InputFileError(None, f"step {spec.name} is the platform's own (run it through the API)")
    summary = spec.resolve()(Workspace(args.survey, args.out), options, no_progress, context)
    if args.json:
        print(json.dumps(summary, indent=1, default=str))
    else:
        print(f"{spec.name}: done; outputs in {args.out}", file=sys.stderr)
    return 0


def _stockpiles(path: str) -> list[dict]:
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
        feats = doc["features"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputFileError(p, f"not a GeoJSON FeatureCollection ({exc})") from None
    out = []
    for i, f in enumerate(feats):
        props = f.get("properties") or {}
        name = str(props.get("name") or f"pile {i + 1}")
        out.append({"id": str(props.get("id") or name), "name": name, "base": str(props.get("base") or "lowest"),
                    "outline": f.get("geometry")})
    return out
