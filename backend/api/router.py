"""All /api/v1 routes."""

from __future__ import annotations

from fastapi import APIRouter

from .routes import auth, health, results, runs, schedules, sites, stockpiles, surveys, tokens, uploads, users, webhooks

api_router = APIRouter(prefix="/api/v1")
# FastAPI matches a request against the routes one by one in this order (about 6 us each): the endpoints
# dashboards and GIS systems poll come first
for module in (results, runs, sites, surveys, stockpiles, health, uploads, auth, tokens, users, schedules, webhooks):
    api_router.include_router(module.router)
