"""Celery worker of the Georef platform: thin tasks that advance processing runs one step at a time."""
