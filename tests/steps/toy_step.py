"""A toy pipeline step declared through its spec alone (tests/steps/test_step_contract.py): loaded as a step
plug-in (GEOREF_STEP_PLUGINS=tests.steps.toy_step), it must appear in the CLI, the API's schema, the
worker and the browser's options and downloads without any other change."""

from __future__ import annotations

from georef_core.steps.contract import Option, Output, Product, StepSpec, register


def run(workspace, options: dict, progress, context: dict) -> dict:
    greeting = options.get("greeting") or "hello"
    repeat = int(options.get("repeat") or 1)
    out = workspace.path("toy", "hello")
    out.parent.mkdir(parents=True, exist_ok=True)
    names = sorted(p.name for p in workspace.survey_dir.rglob("*") if p.is_file())
    out.write_text("\n".join([f"{greeting}, {context.get('crs') or 'no crs'}"] * repeat + names) + "\n")
    if progress:
        progress("toy", 1, 1)
    return {"lines": repeat, "survey_files": len(names)}


TOY = register(StepSpec(
    name="toy", title="Toy step", version=1, description="Writes a greeting and the survey's file names.",
    function="tests.steps.toy_step:run",
    options=(Option("greeting", "string", "hello", "the greeting", choices=("hello", "hi")),
             Option("repeat", "integer", 1, "how many times", minimum=1, maximum=5)),
    outputs=(Output("hello", "toy/hello.txt", "the greeting", "text/plain"),),
    products=(Product("files/toy/hello.txt", "Toy greeting", "the toy step's file", ("hello",), (("", "text"),)),),
    summary={"lines": "greetings written", "survey_files": "files seen"},
))
