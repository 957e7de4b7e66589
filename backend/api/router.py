"""All /api/v1 routes."""

from __future__ import annotations

from fastapi import FastAPI

from .routes import (auth, calibrations, designs, file_kinds, health, results, runs, schedules, sites, steps,
                     stockpiles, surveys, tiles, tokens, uploads, users, webhooks)

API_PREFIX = "/api/v1"
# FastAPI matches a request against the routes one by one in this order: the endpoints dashboards and GIS
# systems poll come first. Each module's router is included in the app itself, with the prefix: every
# level of router nesting makes FastAPI scan the routes of that level twice per request.
API_MODULES = (results, tiles, runs, sites, surveys, stockpiles, health, uploads, auth, tokens, users, schedules,
               webhooks, steps, file_kinds, designs, calibrations)


def include_api(app: FastAPI) -> None:
    for module in API_MODULES:
        app.include_router(module.router, prefix=API_PREFIX)
