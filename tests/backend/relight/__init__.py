"""Tests of backend/relight/."""
