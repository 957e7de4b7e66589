"""A toy step that can run as parts on several workers (contract.Split), declared through its spec alone:
loaded as a plug-in (GEOREF_STEP_PLUGINS=tests.steps.toy_split_step) by tests/worker/test_split_steps.py.
The plan writes a shared file, every part sums a slice of the survey's bytes and says which process ran
it, the merge checks every part and writes the result; run_split gives the same result in one process."""

from __future__ import annotations

import hashlib
import json
import os
import time

from georef_core.errors import ProcessingError
from georef_core.steps.contract import Option, Output, Split, StepSpec, register, run_split


def _files(workspace) -> list:
    return sorted(p for p in workspace.survey_dir.rglob("*") if p.is_file() and not p.name.startswith("."))


def plan(workspace, options: dict, context: dict) -> list[dict]:
    names = [p.relative_to(workspace.survey_dir).as_posix() for p in _files(workspace)]
    shared = workspace.out_dir / "toysplit" / "plan.json"
    shared.parent.mkdir(parents=True, exist_ok=True)
    shared.write_text(json.dumps({"files": names}))
    n = int(options.get("parts") or 3)
    parts = [{"files": names[k::n]} for k in range(n)]
    if options.get("phases"):   # a second phase: one part that reads the first parts' files (contract.Split "after")
        parts.append({"files": [], "after": list(range(n))})
    return parts


def part(workspace, options: dict, part: dict, progress, context: dict) -> None:
    shared = json.loads((workspace.out_dir / "toysplit" / "plan.json").read_text())   # the plan's file reaches the part
    if options.get("fail_part") is not None and int(options["fail_part"]) == part["index"]:
        raise ProcessingError(f"toy part {part['index']} failed as asked")
    digest = hashlib.sha256()
    for k, name in enumerate(part["files"]):
        digest.update((workspace.survey_dir / name).read_bytes())
        if progress:
            progress("toy parts", k + 1, len(part["files"]))
    time.sleep(float(options.get("work_s") or 0.0))
    read = {}
    for j in part.get("after") or []:   # the earlier parts' results, found in this part's workspace
        read[j] = json.loads((workspace.part_dir("toysplit", j) / "part.json").read_text())["sha256"]
        digest.update(read[j].encode())
    out = workspace.part_dir("toysplit", part["index"]) / "part.json"
    out.write_text(json.dumps({"index": part["index"], "files": part["files"], "sha256": digest.hexdigest(),
                               "of": len(shared["files"]), "pid": os.getpid(), "read": sorted(read)}))


def merge(workspace, options: dict, parts: list[dict], progress, context: dict) -> dict:
    done = [json.loads((workspace.part_dir("toysplit", p["index"]) / "part.json").read_text()) for p in parts]
    if sorted(d["index"] for d in done) != list(range(len(parts))):
        raise ProcessingError("a part is missing")
    result = workspace.path("toysplit", "result")
    result.write_text(json.dumps({"parts": [{k: d[k] for k in ("index", "files", "sha256", "read")} for d in done]},
                                 indent=1))
    return {"parts": len(done), "processes": len({d["pid"] for d in done}),
            "files": sum(len(d["files"]) for d in done), "read": [d["read"] for d in done]}


def run(workspace, options: dict, progress, context: dict) -> dict:
    return run_split(TOY_SPLIT, workspace, options, progress, context)


TOY_SPLIT = register(StepSpec(
    name="toysplit", title="Toy split step", version=1, description="Hashes the survey's files in parts.",
    function="tests.steps.toy_split_step:run",
    split=Split(plan="tests.steps.toy_split_step:plan", part="tests.steps.toy_split_step:part",
                merge="tests.steps.toy_split_step:merge"),
    options=(Option("parts", "integer", 3, "parts", minimum=1, maximum=16),
             Option("work_s", "number", 0.0, "seconds each part waits", minimum=0.0, maximum=30.0),
             Option("fail_part", "integer", None, "this part raises", minimum=0, maximum=15),
             Option("phases", "boolean", False, "a last part reads the others' files (after them)")),
    outputs=(Output("result", "toysplit/result.json", "the parts' hashes", "application/json"),),
    summary={"parts": "parts merged", "processes": "processes that ran them", "files": "files hashed",
             "read": "per part, the earlier parts whose files it read"},
))
