"""The step contract: what a pipeline step declares once, and every layer reads.

A step is a function plus its StepSpec: typed options (validated before anything runs, exported as JSON
Schema for the API and the browser), the survey inputs it reads, its output files (names in one place: the
Workspace resolves them, the API serves them, the UI lists them as downloads), what its summary holds, and a
version that invalidates reuse when the code changes its results. The CLI (`georef steps`, `georef step`),
the worker (worker/pipeline.py), the API (backend/services/steps_catalog.py: run planning, settings
validation, result paths, GET /steps) and the UI (options form and downloads from that schema) read the
specs; adding a step is writing its function and its spec (docs/architecture.md).

Pure Python: importing this module (and georef_core.steps.specs) loads no science code, so the API can plan
runs and validate settings without numpy or pycolmap.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..errors import ProcessingError

__all__ = ["Option", "OptionError", "Output", "Product", "Split", "StepSpec", "StepUnavailable", "Workspace",
           "all_specs", "check_part_order", "get_spec", "load_plugins", "options_from_dataclass", "part_after",
           "part_file_read", "part_prefix", "register",
           "resolve_function", "run_split", "unregister"]

KINDS = ("number", "integer", "string", "boolean", "numbers", "object")


class OptionError(ProcessingError):
    """A step option that is unknown or not of its declared type, range or choices."""

    def __init__(self, step: str, name: str, problem: str):
        self.step, self.name, self.problem = step, name, problem
        super().__init__(f"{step} settings: {name}: {problem}")


@dataclass(frozen=True)
class Option:
    """One option of a step. kind: number | integer | string | boolean | numbers (a list of numbers, of
    `length` when given) | object (a JSON object, checked by the step itself)."""

    name: str
    kind: str
    default: Any = None
    help: str = ""
    choices: tuple[str, ...] | None = None
    minimum: float | None = None
    maximum: float | None = None
    length: int | None = None       # numbers: exact length
    unit: str | None = None
    nullable: bool = True           # None (JSON null) means "the step's default"
    advanced: bool = False          # the UI shows it under "advanced"

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"option {self.name}: kind {self.kind!r} is not one of {KINDS}")

    def check(self, step: str, value):
        """The value, checked and normalised (int for integer, float for number, list of floats for
        numbers); raises OptionError."""
        def bad(problem):
            return OptionError(step, self.name, problem)

        if value is None:
            if self.nullable:
                return None
            raise bad("must be given (null is not allowed)")
        k = self.kind
        if k == "boolean":
            if not isinstance(value, bool):
                raise bad(f"{value!r} is not true or false")
            return value
        if k == "string":
            if not isinstance(value, str):
                raise bad(f"{value!r} is not text")
            if self.choices is not None and value not in self.choices:
                raise bad(f"{value!r} is not one of {', '.join(self.choices)}")
            return value
        if k in ("number", "integer"):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise bad(f"{value!r} is not a number")
            if not math.isfinite(float(value)):
                raise bad(f"{value!r} is not a finite number")
            if k == "integer":
                if float(value) != int(value):
                    raise bad(f"{value!r} is not a whole number")
                value = int(value)
            else:
                value = float(value)
            self._range(value, bad)
            return value
        if k == "numbers":
            if not isinstance(value, (list, tuple)):
                raise bad(f"{value!r} is not a list of numbers")
            if self.length is not None and len(value) != self.length:
                raise bad(f"needs {self.length} numbers, got {len(value)}")
            out = []
            for v in value:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
                    raise bad(f"{v!r} is not a finite number")
                self._range(float(v), bad)
                out.append(float(v))
            return out
        if not isinstance(value, dict):       # object
            raise bad(f"{value!r} is not an object")
        return value

    def _range(self, v: float, bad):
        if self.minimum is not None and v < self.minimum:
            raise bad(f"{v:g} is below the minimum {self.minimum:g}{' ' + self.unit if self.unit else ''}")
        if self.maximum is not None and v > self.maximum:
            raise bad(f"{v:g} is above the maximum {self.maximum:g}{' ' + self.unit if self.unit else ''}")

    def json_schema(self) -> dict:
        base = {"number": {"type": "number"}, "integer": {"type": "integer"}, "string": {"type": "string"},
                "boolean": {"type": "boolean"}, "numbers": {"type": "array", "items": {"type": "number"}},
                "object": {"type": "object"}}[self.kind]
        s = dict(base)
        if self.kind == "numbers" and self.length is not None:
            s["minItems"] = s["maxItems"] = self.length
        if self.choices is not None:
            s["enum"] = list(self.choices)
        if self.minimum is not None:
            (s["items"] if self.kind == "numbers" else s)["minimum"] = self.minimum
        if self.maximum is not None:
            (s["items"] if self.kind == "numbers" else s)["maximum"] = self.maximum
        if self.nullable:
            s = {"anyOf": [s, {"type": "null"}]}
        if self.default is not None:
            s["default"] = list(self.default) if isinstance(self.default, tuple) else self.default
        if self.help:
            s["description"] = self.help
        if self.unit:
            s["x-unit"] = self.unit
        if self.advanced:
            s["x-advanced"] = True
        return s


@dataclass(frozen=True)
class Output:
    """A file a step writes, relative to the run's output folder. `tile`: a georeferenced raster the API
    serves as web map tiles (/runs/{id}/tiles/{key}/...) in this style: rgb (an orthophoto), heights (a
    surface model: colour ramp and hillshade) or difference (signed metres: diverging ramp);
    georef_core/tiles/render.py."""

    key: str
    path: str
    description: str = ""
    media_type: str | None = None
    tile: str | None = None


@dataclass(frozen=True)
class Product:
    """A download a user sees: a result endpoint (/runs/{id}/results/{endpoint}) serving one of the step's
    outputs (`needs`: any of these output keys present) in the listed formats ([query, label], query ""
    for the file as stored)."""

    endpoint: str
    title: str
    description: str
    needs: tuple[str, ...]
    formats: tuple[tuple[str, str], ...] = (("", "file"),)


@dataclass(frozen=True)
class Split:
    """A step that can also run as parts on several workers: plan, then every part (in any order, on any
    worker), then merge. Each is "module:function":

    * plan(workspace, options, context) -> [part descriptor (a JSON object), ...]: cheap, deterministic from the
      step's inputs; may write shared files under the step's folder (recorded, given to every part);
    * part(workspace, options, part, progress, context): writes only under workspace.part_dir(step, index)
      (``part["index"]`` is set by the platform: 0..n-1). A part whose descriptor names ``"after": [indices]``
      (earlier parts) runs once those have succeeded and finds their folders (their files) in its workspace:
      a second phase that reads the first's results (the tiled dense step: depth maps, then the tiles); the
      other parts see none of the other parts' files;
    * merge(workspace, options, parts, progress, context) -> the step's summary: reads the parts' folders,
      writes the declared outputs.

    What a reader is given of the parts' files (on the platform every file of a part is recorded; a reader
    fetches only what it reads): the merge, the files of every part whose path relative to its part folder
    matches one of ``merge_reads`` (fnmatch patterns; empty: all of them); a part with ``"after"``, the files
    of those parts matching its descriptor's ``"reads"`` (patterns; absent: all of them).

    `run_split` runs the three in one process (the CLI, a single worker); the platform sends each part to
    a worker (worker/tasks.py run_part) when the plan has more than one. Both give the same files."""

    plan: str
    part: str
    merge: str
    merge_reads: tuple[str, ...] = ()


def part_file_read(rel_path: str, patterns) -> bool:
    """Whether a part's file (``rel_path``: relative to its part folder) is one a reader declared it reads
    (``patterns``: fnmatch patterns; empty or None: every file)."""
    import fnmatch

    return not patterns or any(fnmatch.fnmatchcase(rel_path, p) for p in patterns)


@dataclass(frozen=True)
class StepSpec:
    name: str
    title: str
    description: str
    version: int
    function: str | None              # "module:function" with the signature (workspace, options, progress, context)
    depends_on: tuple[str, ...] = ()
    soft_after: tuple[str, ...] = ()  # waits for these when they are planned, without needing them
    inputs: tuple[str, ...] = ()      # survey-folder prefixes it reads ("" = everything)
    site_data: tuple[str, ...] = ()   # site-level data it reads (crs, vertical, stockpiles, names)
    heavy: bool = False               # goes to the heavy queue when one is configured
    options: tuple[Option, ...] = ()
    outputs: tuple[Output, ...] = ()
    products: tuple[Product, ...] = ()
    summary: dict[str, str] = field(default_factory=dict)   # key -> what it holds
    split: Split | None = None        # can run as parts on several workers (Split)

    @property
    def settings(self) -> tuple[str, ...]:
        """The settings sections that change its result: its own."""
        return (self.name,)

    def option(self, name: str) -> Option | None:
        return next((o for o in self.options if o.name == name), None)

    def validate(self, values: dict | None) -> dict:
        """The given options checked against the declaration (unknown names, types, ranges, choices);
        returns them normalised. Raises OptionError naming the first bad one."""
        if values is None:
            return {}
        if not isinstance(values, dict):
            raise OptionError(self.name, "(settings)", f"expected an object of options, got {type(values).__name__}")
        out = {}
        for k, v in values.items():
            o = self.option(k)
            if o is None:
                raise OptionError(self.name, k, f"unknown option (known: {', '.join(sorted(x.name for x in self.options))})")
            out[k] = o.check(self.name, v)
        return out

    def output(self, key: str) -> Output:
        for o in self.outputs:
            if o.key == key:
                return o
        raise KeyError(f"step {self.name} declares no output {key!r}")

    def json_schema(self) -> dict:
        return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": self.title,
                "description": self.description, "type": "object", "additionalProperties": False,
                "properties": {o.name: o.json_schema() for o in self.options}}

    def as_dict(self) -> dict:
        """The spec as the API serves it (GET /steps)."""
        return {"name": self.name, "title": self.title, "description": self.description, "version": self.version,
                "depends_on": list(self.depends_on), "soft_after": list(self.soft_after), "inputs": list(self.inputs),
                "site_data": list(self.site_data), "heavy": self.heavy, "parallel_parts": self.split is not None,
                "options_schema": self.json_schema(),
                "outputs": [dataclasses.asdict(o) for o in self.outputs],
                "products": [{"endpoint": p.endpoint, "title": p.title, "description": p.description,
                              "needs": [self.output(k).path for k in p.needs],
                              "formats": [list(f) for f in p.formats]} for p in self.products],
                "summary": dict(self.summary)}

    def resolve(self) -> Callable:
        """The step's function (StepUnavailable when it has none or it is not installed)."""
        if self.function is None:
            raise StepUnavailable(f"step {self.name} has no function in this installation")
        return resolve_function(self.function)


class StepUnavailable(ProcessingError):
    """A step's function is not installed here (its module or function is missing)."""


def resolve_function(target: str) -> Callable:
    """'package.module:function' -> the function; StepUnavailable when the module or the function is not
    there (a module that exists but fails to import is a bug and raises)."""
    module_name, func_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and (module_name == exc.name or module_name.startswith(exc.name + ".")):
            raise StepUnavailable(f"{module_name} is not installed") from None
        raise
    fn = getattr(module, func_name, None)
    if fn is None:
        raise StepUnavailable(f"{module_name}.{func_name} does not exist")
    return fn


class Workspace:
    """The folders of one run: the survey as uploaded (survey_dir, read only) and the run's outputs
    (out_dir), with every declared output's path (as OpenSfM's DataSet owns a reconstruction's paths)."""

    def __init__(self, survey_dir, out_dir):
        self.survey_dir = Path(survey_dir)
        self.out_dir = Path(out_dir)

    def path(self, step: str, key: str) -> Path:
        return self.out_dir / get_spec(step).output(key).path

    def part_dir(self, step: str, index: int) -> Path:
        """Where part ``index`` of a split step writes (and only there): <out>/<step>/parts/<index>/."""
        return self.out_dir / part_prefix(step, index)


def part_prefix(step: str, index: int | None = None) -> str:
    """The run-relative folder of a split step's parts (all of them when ``index`` is None)."""
    return f"{step}/parts/" if index is None else f"{step}/parts/{int(index):04d}/"


def run_split(spec: "StepSpec", workspace: Workspace, options: dict, progress, context: dict) -> dict:
    """A split step in one process: plan, every part in order, merge (what the platform does across
    workers, with the same files)."""
    parts = [dict(p, index=k) for k, p in enumerate(resolve_function(spec.split.plan)(workspace, options, context))]
    check_part_order(spec.name, parts)
    run_part = resolve_function(spec.split.part)
    for p in parts:
        workspace.part_dir(spec.name, p["index"]).mkdir(parents=True, exist_ok=True)
        run_part(workspace, options, p, progress, context)
    return resolve_function(spec.split.merge)(workspace, options, parts, progress, context)


def part_after(part: dict) -> list[int]:
    """The parts a part waits for and reads (its descriptor's ``after``), as indices."""
    return sorted({int(j) for j in part.get("after") or []})


def check_part_order(step: str, parts: list[dict]) -> None:
    """A plan's ``after`` may name only earlier parts (so the plan's order runs them correctly)."""
    for k, p in enumerate(parts):
        bad = [j for j in part_after(p) if not 0 <= j < k]
        if bad:
            raise ProcessingError(f"step {step}: part {k} waits for part {bad[0]}, which is not an earlier part")


# ------------------------------------------------------------------------------------------------- registry
_REGISTRY: dict[str, StepSpec] = {}


def register(spec: StepSpec) -> StepSpec:
    """Adds a step (its name must be new; dependencies must be registered first)."""
    if spec.name in _REGISTRY:
        raise ValueError(f"step {spec.name!r} is registered already")
    missing = [d for d in spec.depends_on if d not in _REGISTRY]
    if missing:
        raise ValueError(f"step {spec.name!r} depends on unregistered step(s) {', '.join(missing)}")
    _REGISTRY[spec.name] = spec
    return spec


def unregister(name: str) -> None:
    _REGISTRY.pop(name, None)


PLUGINS_ENV = "GEOREF_STEP_PLUGINS"    # comma-separated modules that register more steps when imported
_PLUGINS_LOADED: set[str] = set()


def load_plugins() -> None:
    """Imports the step plug-in modules named in $GEOREF_STEP_PLUGINS (once each): every process that reads
    the registry (CLI, API, worker) sees the same steps."""
    import os

    for name in filter(None, (m.strip() for m in os.environ.get(PLUGINS_ENV, "").split(","))):
        if name not in _PLUGINS_LOADED:
            _PLUGINS_LOADED.add(name)
            importlib.import_module(name)


def _load_core() -> None:
    if not _REGISTRY:
        from . import specs  # noqa: F401 - registers the core steps
    load_plugins()


def all_specs() -> list[StepSpec]:
    """Every registered step, in pipeline order (registration order)."""
    _load_core()
    return list(_REGISTRY.values())


def get_spec(name: str) -> StepSpec:
    _load_core()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ProcessingError(f"unknown step {name!r}; steps are {', '.join(_REGISTRY)}") from None


# ------------------------------------------------------------------------- options from an options dataclass
def _kind_of(tp) -> tuple[str, int | None]:
    origin = typing.get_origin(tp)
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    if origin in (typing.Union, types.UnionType) and len(args) == 1:
        return _kind_of(args[0])
    if tp is bool:
        return "boolean", None
    if tp is int:
        return "integer", None
    if tp is float:
        return "number", None
    if tp is str:
        return "string", None
    if origin in (tuple, list):
        if args and all(a in (float, int) for a in args):
            return "numbers", (len(args) if origin is tuple and Ellipsis not in typing.get_args(tp) else None)
        return "numbers", None
    return "object", None


def options_from_dataclass(cls, help: dict[str, str] | None = None, exclude: tuple[str, ...] = (),
                           **overrides: dict) -> tuple[Option, ...]:
    """Options declared from an options dataclass's fields (type and default), with their help texts and
    per-option overrides (choices, minimum, maximum, unit, advanced, nullable): the step function and its
    spec share one list of names and defaults."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if f.name in exclude:
            continue
        kind, length = _kind_of(hints[f.name])
        # a default made by a factory (a dict, a nested options group) is the step's own: none declared
        default = None if f.default is dataclasses.MISSING or isinstance(f.default, dict) else f.default
        kw = dict(name=f.name, kind=kind, default=default, help=(help or {}).get(f.name, ""), length=length)
        kw.update(overrides.get(f.name, {}))
        out.append(Option(**kw))
    return tuple(out)
