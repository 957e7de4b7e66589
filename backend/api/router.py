"""All /api/v1 routes."""

from __future__ import annotations

from fastapi import APIRouter

from .routes import auth, health, results, runs, schedules, sites, stockpiles, surveys, tokens, uploads, users, webhooks

api_router = APIRouter(prefix="/api/v1")
for module in (auth, tokens, users, sites, surveys, uploads, runs, results, stockpiles, schedules, webhooks, health):
    api_router.include_router(module.router)
